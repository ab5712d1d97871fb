"""Assembly Agent application layer: command line, web server, pipeline worker, storage."""
