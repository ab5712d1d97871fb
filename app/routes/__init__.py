"""The HTTP API as FastAPI routers, one module per resource; :mod:`app.routes.deps` holds their dependencies."""
