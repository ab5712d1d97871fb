"""``/ws``: one JSON snapshot per processed frame; a slow client skips to the newest one.

``/ws?image=1`` (the panel): each snapshot's text message is followed by a binary message, the JPEG of that
same frame's colour image, so the panel shows image and state of one frame together without an HTTP
request per frame. Snapshot JSON and JPEG are encoded once per frame for all clients.
"""

from __future__ import annotations

import asyncio
import contextlib

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from app.routes.deps import State

router = APIRouter()


@router.websocket("/ws")
async def ws(websocket: WebSocket, state: State) -> None:
    """Stream snapshots (and with ``?image=1`` their JPEGs) until the client leaves."""
    await websocket.accept()
    with_image = websocket.query_params.get("image") in ("1", "true")
    quality = state.settings.jpeg_quality
    loop = asyncio.get_running_loop()
    event = asyncio.Event()
    closed = asyncio.Event()

    def on_snapshot(_snap) -> None:
        loop.call_soon_threadsafe(event.set)

    async def watch_disconnect() -> None:
        # Notices a client that left (or a server shutdown) even while no frame arrives.
        try:
            while (await websocket.receive())["type"] != "websocket.disconnect":
                pass
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            closed.set()
            event.set()

    state.worker.add_listener(on_snapshot)
    watcher = asyncio.create_task(watch_disconnect())
    sent = -1
    try:
        while not closed.is_set():
            event.clear()  # cleared before reading: a snapshot published from now on wakes us again
            if with_image:  # JPEG encoding (once per frame) off the event loop
                got = await asyncio.to_thread(state.worker.frame_message, True, quality)
            else:
                got = state.worker.frame_message(False)
            if got is not None and got[0] != sent:
                sent = got[0]
                await websocket.send_text(got[1])
                if got[2] is not None:
                    await websocket.send_bytes(got[2])
                continue
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(event.wait(), timeout=5.0)
    except (WebSocketDisconnect, RuntimeError):
        pass
    finally:
        state.worker.remove_listener(on_snapshot)
        watcher.cancel()
