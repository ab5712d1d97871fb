"""``/ws``: one JSON snapshot per processed frame; a slow client skips to the newest one."""

from __future__ import annotations

import asyncio
import contextlib

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from app.routes.deps import State

router = APIRouter()


@router.websocket("/ws")
async def ws(websocket: WebSocket, state: State) -> None:
    """Stream snapshots until the client leaves; the JSON is encoded once per snapshot for all clients."""
    await websocket.accept()
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
            got = state.worker.snapshot_json()
            if got is not None and got[0] != sent:
                sent = got[0]
                await websocket.send_text(got[1])
                continue
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(event.wait(), timeout=5.0)
    except (WebSocketDisconnect, RuntimeError):
        pass
    finally:
        state.worker.remove_listener(on_snapshot)
        watcher.cancel()
