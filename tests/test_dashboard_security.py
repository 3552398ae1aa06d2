"""Issue 19, dashboard items, each as the attack it stops: a web page of another origin driving
a loopback dashboard, --expose without its token, launch-form values outside their options
(a task path leaving configs/, any --model, seeds out of range, overrides that import code,
more launches than the cap), and a /scene mesh path outside the assets root."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from websockets.exceptions import InvalidStatus

from server import launch
from server.access import AccessPolicy
from server.launch import Launcher, LaunchOptions, LaunchRefused, LaunchRequest, parse_overrides
from server.scene_geometry import find_mesh
from tests.dashboard_fixtures import HeadlessClient, make_runs, start_dashboard

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("security") / "runs"
    make_runs(root, models=("mlp",), broken=False, iterations=3, frames=4)
    return root


# --- who may connect ----------------------------------------------------------------------
def test_a_page_of_another_origin_cannot_open_the_websocket(runs: Path) -> None:
    server, dashboard, url = start_dashboard(runs)
    try:
        for origin in ("http://evil.example", "http://127.0.0.1.evil.example:8080", "null",
                       "file://"):
            with pytest.raises(InvalidStatus) as refused:
                HeadlessClient(url, origin=origin)
            assert refused.value.response.status_code == 403
        assert not dashboard.sessions, "a refused page got no session (saw nothing)"
        port = server.get_port()
        for origin in (f"http://127.0.0.1:{port}", f"http://localhost:{port}", None):
            client = HeadlessClient(url, origin=origin)
            client.wait_for(lambda: "Runs" in client.text() or len(client.elements) > 10,
                            what="the panels")
            client.close()
    finally:
        server.stop()


def test_expose_requires_the_token_from_the_printed_url(runs: Path) -> None:
    server, dashboard, url = start_dashboard(runs, policy=AccessPolicy(expose=True, token="s3cret"))
    try:
        with pytest.raises(InvalidStatus):
            HeadlessClient(url)
        with pytest.raises(InvalidStatus):
            HeadlessClient(url + "/?token=wrong")
        with pytest.raises(urllib.error.HTTPError) as page:
            urllib.request.urlopen(url + "/")
        assert page.value.code == 403
        ok = urllib.request.urlopen(url + "/?token=s3cret")
        cookie = ok.headers["Set-Cookie"]
        assert ok.status == 200 and "HttpOnly" in cookie and "SameSite=Strict" in cookie
        by_cookie = HeadlessClient(url, headers={"Cookie": cookie.split(";")[0]})
        by_cookie.wait_for(lambda: len(by_cookie.elements) > 10, what="the panels")
        by_cookie.close()
        host = url.removeprefix("http://")
        with pytest.raises(InvalidStatus):  # the token does not make a foreign page welcome
            HeadlessClient(url + "/?token=s3cret", origin="http://evil.example")
        same_origin = HeadlessClient(url + "/?token=s3cret", origin=f"http://{host}")
        same_origin.close()
    finally:
        server.stop()


def test_the_cli_prints_a_token_when_exposed(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "server.cli", "--runs", str(tmp_path),
                             "--port", "0", "--expose"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        assert proc.stdout is not None
        lines = []
        for line in proc.stdout:
            lines.append(line)
            if "token" in line and "detach-dashboard: http" in line:
                break
        url = re.search(r"(http://\S+)", lines[-1]).group(1)
        token = url.split("?token=")[1]
        assert len(token) >= 24
        with pytest.raises(urllib.error.HTTPError):
            urllib.request.urlopen(url.split("?")[0], timeout=10)
        assert urllib.request.urlopen(url, timeout=10).status == 200
    finally:
        proc.terminate()
        proc.wait(timeout=20)


# --- the launch form --------------------------------------------------------------------
@pytest.fixture()
def sleeper(monkeypatch):
    """Launches start a 30 s sleep instead of a training run (the command is recorded)."""
    started = []

    def command(task_file, model, seed, runs_dir, overrides=()):
        started.append((Path(task_file), model, seed, tuple(overrides)))
        return [sys.executable, "-c", "import time; time.sleep(30)"]

    monkeypatch.setattr(launch, "launch_command", command)
    return started


def test_values_outside_the_options_are_refused(runs: Path, sleeper) -> None:
    """A websocket client can send any value for a dropdown: the server checks every value
    against its own lists (viser keeps the value the client sent)."""
    options = LaunchOptions.find()
    assert options is not None and "lh1" in options.tasks
    server, dashboard, url = start_dashboard(runs, launcher=Launcher(options, runs, limit=1),
                                             allow_launch=True)
    client = HeadlessClient(url)
    try:
        client.wait_for(lambda: _has(client, "Start run"), what="the launch form")
        attacks = [
            ("Task", "../../../etc/passwd", "task"), ("Task", "base/lh", "task"),
            ("Model", "/tmp/evil.yaml", "model"), ("Model", "../tasks/lh1", "model"),
            ("Seed", -1, "seed"), ("Seed", 2**31, "seed"),
            ("Overrides", "model.kind=os:system", "cannot be set"),
            ("Overrides", "--dry-run", "must be key=value"),
            ("Overrides", "scene[0].source=/etc/passwd", "must be key=value"),
        ]
        for label, value, said in attacks:
            _reset_form(client)
            client.set(label, value)
            time.sleep(0.3)
            before = client.text()
            client.click("Start run")
            client.wait_for(lambda: client.text() != before and "Not started" in client.text()
                            and said in client.text(), what=f"refusal of {label}={value!r}")
        assert sleeper == [], "nothing was started"
        assert dashboard.launcher.launched == []
    finally:
        client.close()
        server.stop()


def _has(client: HeadlessClient, label: str) -> bool:
    try:
        client.find(label, timeout=0.0)
        return True
    except KeyError:
        return False


def _reset_form(client: HeadlessClient) -> None:
    client.set("Task", "lh1")
    client.set("Model", "mlp")
    client.set("Seed", 0)
    client.set("Overrides", "")
    time.sleep(0.2)


def test_launches_are_capped_and_the_task_file_stays_in_configs(tmp_path: Path, sleeper) -> None:
    options = LaunchOptions.find()
    launcher = Launcher(options, tmp_path, limit=2)
    request = options.validate("lh1", "mlp", 3, "train.max_iterations=5 +rewards.terms.x=0.1")
    assert request == LaunchRequest("lh1", "mlp", 3, ("train.max_iterations=5",
                                                      "+rewards.terms.x=0.1"))
    try:
        launcher.start(request)
        launcher.start(request)
        with pytest.raises(LaunchRefused, match="at most 2 at a time"):
            launcher.start(request)
        assert len(sleeper) == 2 and sleeper[0][0] == options.configs / "tasks" / "lh1.yaml"
        with pytest.raises(LaunchRefused, match="not a file"):
            options.task_file("../../pyproject")
        for seed in (True, 1.5, "3", -1, 2**31):
            with pytest.raises(LaunchRefused, match="seed"):
                options.validate("lh1", "mlp", seed, "")
        for text in ("'unclosed", "a=b\nc=d", "sim.num_envs=8 ; rm -rf /"):
            with pytest.raises(LaunchRefused):
                parse_overrides(text)
    finally:
        for run in launcher.launched:
            run.proc.kill()
            run.proc.wait()


# --- files a log may name -----------------------------------------------------------------------
def test_a_scene_mesh_outside_the_assets_root_is_never_opened(tmp_path: Path, monkeypatch) -> None:
    assets = tmp_path / "assets"
    inside = assets / "chair" / "chair_v0" / "mesh.obj"
    inside.parent.mkdir(parents=True)
    inside.write_text("v 0 0 0\n")
    secret = tmp_path / "secret" / "chair" / "leak" / "mesh.obj"
    secret.parent.mkdir(parents=True)
    secret.write_text("v 1 1 1\n")
    (assets / "chair" / "link").symlink_to(secret.parent, target_is_directory=True)
    monkeypatch.setenv("DETACH_ASSETS", str(assets))
    monkeypatch.chdir(tmp_path)
    assert find_mesh("chair/chair_v0/mesh.obj") == inside.resolve()
    assert find_mesh("/elsewhere/assets/chair/chair_v0/mesh.obj") == inside.resolve()
    for name in (str(secret), "../secret/chair/leak/mesh.obj", "../../secret/chair/leak/mesh.obj",
                 "chair/../../secret/chair/leak/mesh.obj", "chair/link/mesh.obj", "/etc/passwd",
                 "chair/chair_v0/../../../secret/chair/leak/mesh.obj", "", None):
        assert find_mesh(name) is None, name
    assert os.path.exists(secret)


def test_the_dashboard_looks_for_meshes_where_the_cli_builds_them(tmp_path: Path, monkeypatch) -> None:
    """One assets root for training and drawing ($DETACH_ASSETS, else ./assets): before, the
    dashboard also searched ./assets when $DETACH_ASSETS was set and an assets/ folder beside
    the runs folder, so it could draw a mesh the run never used."""
    for root in ("built", "assets"):
        mesh = tmp_path / root / "chair" / "chair_v0" / "mesh.obj"
        mesh.parent.mkdir(parents=True)
        mesh.write_text("v 0 0 0\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("DETACH_ASSETS", str(tmp_path / "built"))
    assert find_mesh("chair/chair_v0/mesh.obj") == (tmp_path / "built" / "chair" / "chair_v0" / "mesh.obj").resolve()
    monkeypatch.setenv("DETACH_ASSETS", str(tmp_path / "empty"))
    assert find_mesh("chair/chair_v0/mesh.obj") is None  # ./assets is not also searched
