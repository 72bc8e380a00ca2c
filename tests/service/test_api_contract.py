"""The API keeps its OpenAPI contract: a bounded schemathesis run against a real server (uvicorn
in a thread, a throwaway scenes folder, a frame generator in the solver's place) finds no 5xx and
no answer the schema does not describe; and the HTTP edges the fuzzer does not reach: OPTIONS,
405s, a body that never arrives."""

from __future__ import annotations

import functools
import re
import shutil
import socket
import tempfile
import time
from pathlib import Path

import pytest

schemathesis = pytest.importorskip("schemathesis")
import httpx  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402

from server.app import create_app  # noqa: E402
from server.bench import frame_generator  # noqa: E402
from server.settings import Settings  # noqa: E402
from tests.support.scenes import tiny_toml  # noqa: E402
from tests.support.service import on_uvicorn  # noqa: E402

# Statuses a schema-valid request may get. 422 among them: what a scene's TOML must hold, the
# live parameters' ranges (named by the solver process at run time) and the scene's own rules
# are beyond a JSON schema. Names are not: the schema's name rule is checked on its own below.
# 429: the runs the fuzzer starts paused fill the run queue.
ACCEPTED = ["2xx", "404", "409", "422", "429", "503"]
# A run's result, summary, forming limits and recording exist once it has ended (its
# recording once it has a frame): a 404 for a run just created is the documented answer there,
# not a created resource gone missing. Which sequences the stateful phase draws depends on the
# whole schema, so any new route or field may lead it there.
LATER = r"/\{run_id\}/(result|summary|forming_limits|recording|plots)$"
CONFIG = schemathesis.Config.from_dict({
    "generation": {"deterministic": True},
    "checks": {"positive_data_acceptance": {"expected-statuses": ACCEPTED}},
    "operations": [{"include-path-regex": LATER,
                    "checks": {"ensure_resource_availability": {"enabled": False}}}]})
# the document does not depend on the folders or the worker: the app served below has the same
SCHEMA = schemathesis.openapi.from_dict(create_app(Settings(viewer=False)).openapi(),
                                        config=CONFIG)
# derandomize: the same examples every run; no deadline: the machine may be loaded
FUZZ = settings(max_examples=8, derandomize=True, deadline=None,
                suppress_health_check=list(HealthCheck))


@pytest.fixture(scope="module")
def base_url():
    """The service on a throwaway scenes folder (the stateful phase deletes scenes), with a
    frame generator for a solver: runs start, step and stop at once and need no solver."""
    root = Path(tempfile.mkdtemp(prefix="q3t-contract-"))
    (root / "scenes").mkdir()
    # named as in the schema's examples, so that those start runs
    (root / "scenes" / "cantilever.toml").write_text(tiny_toml())
    s = Settings(scenes_dir=root / "scenes", runs_dir=root / "runs", viewer=False,
                 max_body=64_000)
    app = create_app(s, worker_target=functools.partial(frame_generator, n_vertices=64,
                                                        rate=200.0))
    try:
        with on_uvicorn(app) as url:
            yield url
        manager = app.state.manager  # shut down: the run the fuzzer left is over, no process
        assert manager.active_runs() == [] and not manager.slots[0].worker.alive()
    finally:
        shutil.rmtree(root)


@SCHEMA.parametrize()
@FUZZ
def test_every_operation_keeps_the_contract(case, base_url):
    case.call_and_validate(base_url=base_url)


def reset(base_url: str) -> None:
    """Back to one scene and no run: every sequence of calls starts from the same state (what
    hypothesis draws follows the answers, and it replays sequences)."""
    for run in httpx.get(base_url + "/api/runs").json():
        url = f"{base_url}/api/runs/{run['id']}"
        deadline = time.monotonic() + 60
        while httpx.delete(url).status_code == 409:  # active: stop it first
            httpx.post(url + "/stop")
            assert time.monotonic() < deadline, httpx.get(url).text
            time.sleep(0.02)
    for scene in httpx.get(base_url + "/api/scenes").json():
        httpx.delete(f"{base_url}/api/scenes/{scene['name']}")
    httpx.put(base_url + "/api/scenes/cantilever", json={"toml": tiny_toml()})


def test_sequences_of_calls_keep_the_contract(base_url):
    class Calls(SCHEMA.as_state_machine()):
        def setup(self):
            reset(base_url)

        def get_call_kwargs(self, case):
            return {"base_url": base_url}

    Calls.run(settings=settings(FUZZ, max_examples=15, stateful_step_count=6))


def test_error_answers_are_what_the_schema_says():
    """One error shape, documented: every 4xx a route declares is a Problem ({"detail": str},
    as the server sends); FastAPI's own validation-error array is nowhere (its 422s are
    Problems too)."""
    doc = create_app(Settings(viewer=False)).openapi()
    assert "HTTPValidationError" not in doc["components"]["schemas"]
    assert doc["components"]["schemas"]["Problem"]["properties"]["detail"]["type"] == "string"
    declared = 0
    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            for status, answer in op["responses"].items():
                if status.startswith("4"):
                    ref = answer["content"]["application/json"]["schema"]["$ref"]
                    assert ref.endswith("/Problem"), (method, path, status)
                    declared += 1
            named = "{" in path or "requestBody" in op
            assert not named or "422" in op["responses"], (method, path)
    assert declared > 40


def test_names_valid_by_the_schema_are_accepted_and_the_rest_refused():
    """The name rule in the schema (pattern and lengths) is the rule the server applies."""
    from hypothesis import given
    from hypothesis import strategies as st

    from server.problems import Invalid
    from server.settings import NAME_PATTERN, RESERVED_SCENE_NAMES, SCENE_NAME_MAX, check_scene_name

    doc = create_app(Settings(viewer=False)).openapi()
    rule = doc["components"]["schemas"]["NewScene"]["properties"]["name"]
    assert rule["pattern"] == NAME_PATTERN and rule["maxLength"] == SCENE_NAME_MAX
    assert rule["not"] == {"enum": list(RESERVED_SCENE_NAMES)}
    pattern = re.compile(NAME_PATTERN)

    @given(st.from_regex(NAME_PATTERN, fullmatch=True) | st.text(max_size=90))
    @settings(FUZZ, max_examples=300)
    def agree(name):
        valid = (bool(pattern.fullmatch(name)) and 1 <= len(name) <= SCENE_NAME_MAX
                 and name not in RESERVED_SCENE_NAMES)
        try:
            check_scene_name(name)
            accepted = True
        except Invalid:
            accepted = False
        assert accepted == valid, name

    agree()
    for name in ("a..b", ".hidden", "a/b", "x" * 81, "schema", "tiny\n"):
        with pytest.raises(Invalid):
            check_scene_name(name)


@pytest.fixture(scope="module")
def quick_server():
    """The service with a body deadline of 0.5 s, on an empty scenes folder."""
    root = Path(tempfile.mkdtemp(prefix="q3t-http-"))
    s = Settings(scenes_dir=root / "scenes", runs_dir=root / "runs", viewer=False,
                 body_timeout=0.5)
    app = create_app(s, worker_target=functools.partial(frame_generator, n_vertices=64))
    try:
        with on_uvicorn(app) as url:
            yield url
    finally:
        shutil.rmtree(root)


@pytest.mark.parametrize("path,allow", [
    ("/api/scenes", "GET, POST, OPTIONS"),
    ("/api/scenes/tiny", "GET, PUT, DELETE, OPTIONS"),
    ("/api/scenes/schema", "GET, OPTIONS"),
    ("/api/runs/some-run", "GET, DELETE, OPTIONS"),
    ("/api/runs/some-run/stop", "POST, OPTIONS"),
])
def test_options_lists_every_method_of_the_path(quick_server, path, allow):
    r = httpx.options(quick_server + path)
    assert r.status_code == 204 and r.headers["allow"] == allow, (r.status_code, r.headers)


@pytest.mark.parametrize("method,path,allow", [
    ("POST", "/api/runs/0/frames", "GET, OPTIONS"),
    ("POST", "/api/runs/0/result", "GET, OPTIONS"),
    ("POST", "/api/runs/0/recording", "GET, OPTIONS"),
    ("PUT", "/api/scenes/schema", "GET, OPTIONS"),  # the schema, not a scene named "schema"
    ("GET", "/api/scenes/validate", "POST, OPTIONS"),
    ("PATCH", "/api/scenes/tiny", "GET, PUT, DELETE, OPTIONS"),
])
def test_a_method_the_path_lacks_is_405_naming_those_it_has(quick_server, method, path, allow):
    r = httpx.request(method, quick_server + path)
    assert r.status_code == 405 and r.headers["allow"] == allow, (r.status_code, r.text)
    assert r.json() == {"detail": "Method Not Allowed"}


def test_a_body_that_never_arrives_is_408_and_the_connection_closed(quick_server):
    """A client that sends headers and part of its body, then nothing: the server answers 408
    after its body deadline and closes the connection (it held it for ever)."""
    host, port = quick_server.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port))) as sock:
        sock.sendall(b"PUT /api/scenes/slow HTTP/1.1\r\nHost: x\r\n"
                     b"Content-Type: application/json\r\nContent-Length: 100\r\n\r\n{\"toml\": ")
        sock.settimeout(60)  # generous: the deadline is the server's, not this wait's
        answer = b""
        while chunk := sock.recv(4096):  # until the server closes the connection
            answer += chunk
    head, _, body = answer.partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 408 "), answer
    assert b"connection: close" in head.lower()
    assert b"not received within 0.5 s" in body
    assert httpx.get(quick_server + "/api/scenes").json() == []  # nothing was saved
