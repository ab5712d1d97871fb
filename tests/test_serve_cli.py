"""``assembly-agent serve`` refuses to start, with the option to change, on a busy port or an unusable --source."""

from __future__ import annotations

import socket

from app.cli import main


def test_busy_port_names_the_port_option(tmp_path, capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        rc = main(["serve", "--port", str(port), "--viser-port", "0", "--database", str(tmp_path / "a.sqlite3")])
    assert rc == 1
    err = capsys.readouterr().err
    assert f"port {port}" in err and "--port" in err


def test_unusable_source_fails_at_start(tmp_path, capsys):
    rc = main(["serve", "--source", f"recording:{tmp_path / 'missing'}", "--viser-port", "0",
               "--database", str(tmp_path / "a.sqlite3")])
    assert rc == 1
    err = capsys.readouterr().err
    assert "cannot open --source recording:" in err and "not found" in err
