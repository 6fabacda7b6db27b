"""No Docker engine runs here, so docker-compose.yml and the Dockerfile are checked against the code instead."""

from __future__ import annotations

import importlib.util
import re
import tomllib
from pathlib import Path
from urllib.parse import urlsplit

import pytest
import yaml

from services.cli import COMMANDS, build_parser
from services.common.settings import Settings

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
SERVICES = COMPOSE["services"]
APP = ("api", "worker", "migrate")


def _env(name: str) -> dict[str, str]:
    env = SERVICES[name].get("environment", {})
    return {str(k): str(v) for k, v in env.items()}


def test_all_parts_are_there_with_health_checks():
    assert set(SERVICES) == {"api", "worker", "migrate", "redis", "postgres"}
    for name in ("api", "worker", "redis", "postgres"):
        assert "test" in SERVICES[name]["healthcheck"], name
    assert SERVICES["migrate"].get("restart") == "no"


@pytest.mark.parametrize("name", APP)
def test_commands_name_real_cli_commands(name):
    cmd = SERVICES[name]["command"]
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert cmd[0] == "graspgen" and scripts["graspgen"] == "graspgen.cli:main"
    assert cmd[1] in COMMANDS
    build_parser().parse_args(cmd[1:])  # exits (SystemExit) on an option the CLI does not know


def test_worker_health_check_names_the_celery_app_module():
    test = " ".join(SERVICES["worker"]["healthcheck"]["test"])
    module = re.search(r"-A\s+(\S+)", test).group(1)
    assert importlib.util.find_spec(module) is not None
    from celery.app.utils import find_app

    from services.worker.celery_app import job_task

    app = find_app(module)  # what `celery -A <module>` loads
    assert job_task(app).name == "graspgen.run_job"


@pytest.mark.parametrize("name", APP)
def test_environment_names_exist_in_settings(name):
    fields = {f"GRASPGEN_{f.upper()}" for f in Settings.model_fields}
    env = _env(name)
    assert env, name
    unknown = [k for k in env if k.startswith("GRASPGEN_") and k not in fields]
    assert unknown == []
    Settings(**{k.removeprefix("GRASPGEN_").lower(): v for k, v in env.items()})  # and the values validate


def test_urls_point_at_the_compose_services():
    pg = SERVICES["postgres"]["environment"]
    for name in APP:
        env = _env(name)
        db = urlsplit(env["GRASPGEN_DATABASE_URL"])
        assert db.scheme == "postgresql+psycopg" and db.hostname == "postgres" and db.port == 5432
        assert db.username == pg["POSTGRES_USER"] and db.password == pg["POSTGRES_PASSWORD"]
        assert db.path.lstrip("/") == pg["POSTGRES_DB"]
        broker = urlsplit(env["GRASPGEN_BROKER_URL"])
        assert broker.scheme == "redis" and broker.hostname == "redis" and broker.port == 6379


def test_ports_and_dependencies_line_up():
    api = SERVICES["api"]
    cmd = api["command"]
    port = cmd[cmd.index("--port") + 1]
    host_port, container_port = api["ports"][0].split(":")
    assert container_port == port
    assert f"127.0.0.1:{port}/readyz" in " ".join(api["healthcheck"]["test"])
    for name in ("api", "worker"):
        deps = SERVICES[name]["depends_on"]
        assert deps["migrate"]["condition"] == "service_completed_successfully"
        assert deps["postgres"]["condition"] == deps["redis"]["condition"] == "service_healthy"
    assert SERVICES["migrate"]["depends_on"]["postgres"]["condition"] == "service_healthy"


def test_api_and_worker_share_the_artifact_volume():
    mounts = {}
    for name in ("api", "worker"):
        storage_dir = _env(name)["GRASPGEN_STORAGE_DIR"]
        vols = [v for v in SERVICES[name]["volumes"] if v.split(":")[1] == storage_dir]
        assert vols, name
        mounts[name] = vols[0].split(":")[0]
    assert mounts["api"] == mounts["worker"] and mounts["api"] in COMPOSE["volumes"]


def test_dockerfile_copies_what_exists_and_runs_the_cli():
    build = SERVICES["migrate"]["build"]
    dockerfile = ROOT / build["context"] / build["dockerfile"]
    text = dockerfile.read_text()
    for src in re.findall(r"^COPY\s+(.+?)\s+\S+$", text, flags=re.M):
        for path in src.split():
            assert (ROOT / path).exists(), path
    assert {SERVICES[n].get("image") for n in APP} == {"graspgen:latest"}
    cmd = re.search(r"^CMD\s+(\[.*\])$", text, flags=re.M).group(1)
    assert yaml.safe_load(cmd)[:2] == ["graspgen", "serve"]
