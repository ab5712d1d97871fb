"""The Docker Compose files, validated by ``docker-compose config`` (no Docker engine needed).

``scripts/system-deps.sh`` installs Debian's ``docker-compose`` (v1.29); where it is missing the tests skip with
that reason. The parsed configuration is checked for what the classroom needs: the server built from this
repository and pointed at the PostgreSQL service, which keeps its data in a named volume, and no password
committed (compose refuses to run until one is set).
"""

import shutil
import subprocess
from pathlib import Path
from urllib.parse import urlsplit

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
COMPOSE = shutil.which("docker-compose")
pytestmark = pytest.mark.skipif(COMPOSE is None, reason="docker-compose is not installed (scripts/system-deps.sh)")


def _config(compose_file: str, tmp_path: Path, env: dict[str, str]) -> subprocess.CompletedProcess:
    """``docker-compose -f FILE config`` with exactly ``env`` as the settings (an empty env file, so that a
    developer's docker/.env does not leak in). ``SETUPTOOLS_USE_DISTUTILS=stdlib`` spares docker-compose (Python)
    setuptools' distutils shim, most of its start-up time."""
    env_file = tmp_path / "empty.env"
    env_file.write_text("")
    return subprocess.run([COMPOSE, "-f", str(ROOT / "docker" / compose_file), "--env-file", str(env_file),
                           "config"], capture_output=True, text=True, timeout=60,
                          env={"PATH": "/usr/bin:/bin", "SETUPTOOLS_USE_DISTUTILS": "stdlib", **env})


def test_classroom_compose_points_the_server_at_postgres(tmp_path):
    run = _config("classroom.yaml", tmp_path, {"POSTGRES_PASSWORD": "only-for-this-test-1",
                                               "ASSEMBLY_AGENT_TEACHER_PASSWORD": "teacher-test-pw-2"})
    assert run.returncode == 0, run.stderr
    cfg = yaml.safe_load(run.stdout)
    assert set(cfg["services"]) == {"server", "postgres"}
    server, db = cfg["services"]["server"], cfg["services"]["postgres"]

    assert Path(server["build"]["context"]) == ROOT and server["build"]["dockerfile"] == "docker/Dockerfile"
    assert (ROOT / server["build"]["dockerfile"]).is_file()
    assert server["depends_on"]["postgres"]["condition"] == "service_healthy"
    assert "pg_isready" in " ".join(db["healthcheck"]["test"])

    url = urlsplit(server["environment"]["ASSEMBLY_AGENT_DATABASE"])
    assert url.scheme.startswith("postgresql") and url.hostname == "postgres" and url.port == 5432
    assert url.username == db["environment"]["POSTGRES_USER"] and url.password is None
    assert url.path.lstrip("/") == db["environment"]["POSTGRES_DB"]
    assert server["environment"]["PGPASSWORD"] == db["environment"]["POSTGRES_PASSWORD"] == "only-for-this-test-1"
    assert server["environment"]["ASSEMBLY_AGENT_TEACHER_PASSWORD"] == "teacher-test-pw-2"
    assert float(server["environment"]["ASSEMBLY_AGENT_DATABASE_WAIT_S"]) > 0  # a restarted database is waited for
    assert server["environment"]["ASSEMBLY_AGENT_STATION"] == "classroom-server"  # not the container's random id

    volume, target = db["volumes"][0].split(":")[:2]
    assert target == "/var/lib/postgresql/data" and volume in cfg["volumes"]  # a named volume, not a host path
    assert all(p.startswith("127.0.0.1:") for p in server["ports"] + db["ports"])  # nothing open by default


def test_classroom_compose_refuses_to_run_without_a_database_password(tmp_path):
    run = _config("classroom.yaml", tmp_path, {"ASSEMBLY_AGENT_TEACHER_PASSWORD": "teacher-test-pw-2"})
    assert run.returncode != 0 and "set POSTGRES_PASSWORD in docker/.env" in run.stderr


def test_single_station_compose_is_valid(tmp_path):
    run = _config("compose.yaml", tmp_path, {})
    assert run.returncode == 0, run.stderr
    cfg = yaml.safe_load(run.stdout)
    station = cfg["services"]["assembly-agent"]
    assert Path(station["build"]["context"]) == ROOT and "agent-data" in cfg["volumes"]
    assert any(v.startswith("agent-data:/data") for v in station["volumes"])


def test_committed_env_example_has_no_password():
    """The example env file names the settings but sets no secret (compose refuses empty required values)."""
    values = dict(line.split("=", 1) for line in (ROOT / "docker" / "classroom.env.example").read_text().splitlines()
                  if line and not line.startswith("#"))
    assert values["POSTGRES_PASSWORD"] == "" and values["ASSEMBLY_AGENT_TEACHER_PASSWORD"] == ""
