"""The two HTML pages: the panel (``/``) and the teacher editor (``/teacher``)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import FileResponse

from app.state import WEB_DIR

router = APIRouter(include_in_schema=False)


@router.get("/")
def index() -> FileResponse:
    return FileResponse(WEB_DIR / "templates" / "index.html")


@router.get("/teacher")
def teacher_page() -> FileResponse:
    return FileResponse(WEB_DIR / "templates" / "teacher.html")
