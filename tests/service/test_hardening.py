"""In-process checks of the hardening (issue 25) that need a hook inside the server: a DELETE
landing between a read's look-up and its file reads, where JSON bodies are decoded, how much
of a body the size cap lets in, the served schema under lowered limits, stored phantoms of
older manifests, and the command line's options."""

from __future__ import annotations

import argparse
import asyncio
import json
import shutil

import anyio
import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.cli import build_parser
from service.storage import PhantomStore
from tests.service.test_api import assert_field
from tests.service.test_uploads import upload


@pytest.mark.parametrize("what", ["mesh", "manifest", ""])
def test_a_delete_between_look_up_and_read_gives_404(make_settings, glb_phantom, monkeypatch, what):
    """The audit's race (8 of 600 GETs racing a DELETE gave 500), made deterministic: the phantom's
    directory disappears right after the server decided the id is known."""
    settings = make_settings()
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        pid = upload(client, *glb_phantom()).json()["id"]
        client.app.state.capsule.registry.forget(pid)
        real_load, real_meta = PhantomStore.load, PhantomStore.meta

        def vanish(read):
            def read_after_delete(store, phantom_id):
                shutil.rmtree(store.root / phantom_id, ignore_errors=True)  # the concurrent DELETE
                return read(store, phantom_id)
            return read_after_delete

        monkeypatch.setattr(PhantomStore, "exists", lambda store, phantom_id: True)  # looked up before
        monkeypatch.setattr(PhantomStore, "load", vanish(real_load))
        monkeypatch.setattr(PhantomStore, "meta", vanish(real_meta))
        path = f"/v1/phantoms/{pid}" + (f"/{what}" if what else "")
        assert_field(client.get(path), 404, "path", "phantom_id")


def test_ranging_bodies_are_decoded_off_the_event_loop(api, monkeypatch):
    import service.bodies as bodies

    seen = []
    real = bodies.decode

    def spy(model, body):
        try:
            asyncio.get_running_loop()
            seen.append("event loop")
        except RuntimeError:  # no running loop in this thread: a worker thread
            seen.append("worker thread")
        return real(model, body)

    monkeypatch.setattr(bodies, "decode", spy)
    profile = {"paths": [{"delay_s": 1e-9 * (1 + k), "gain": {"re": 1e-3, "im": 0.0}} for k in range(2000)]}
    r = api.post("/v1/ranging/rss", json={"profile": profile, "trials": 5})
    assert r.status_code == 200, r.text
    assert seen == ["worker thread"]


def test_the_body_cap_stops_pulling_at_the_cap(make_settings):
    """The admission gate on a 640 MB chunked JSON stream (no Content-Length): it pulls about the cap only."""
    from service.admission import Declaration, Gate, Table

    pulled = {"bytes": 0}
    chunk = b" " * 65536

    async def receive():
        pulled["bytes"] += len(chunk)
        return {"type": "http.request", "body": chunk, "more_body": pulled["bytes"] < 10_000 * len(chunk)}

    sent = []

    async def send(message):
        sent.append(message)

    async def app(scope, receive_, send_):  # reads the whole body, as FastAPI does
        from starlette.requests import Request

        try:
            await Request(scope, receive_).body()
        except Exception as exc:  # the cap's HTTPException reaches the app's handlers
            sent.append(exc)

    scope = {"type": "http", "method": "POST", "path": "/v1/ranging/toa", "headers": []}
    table = Table()
    table.find = lambda method, path: Declaration(body=lambda s: 1_000_000, cost="test")  # type: ignore[method-assign]
    anyio.run(Gate(app, table=lambda: table, settings=make_settings()), scope, receive, send)
    assert getattr(sent[0], "status_code", None) == 413
    assert pulled["bytes"] <= 1_000_000 + len(chunk)


def test_the_served_schema_states_this_servers_limits(make_settings):
    settings = make_settings(max_rays=2000, max_trials=20, max_band_points=11, max_receivers=4)
    schema = create_app(settings).openapi()["components"]["schemas"]
    rays = schema["ChannelRequest"]["properties"]["rays"]["anyOf"][0]
    assert rays["maximum"] == 2000
    assert all(example.get("rays", 0) <= 2000 for example in schema["ChannelRequest"]["examples"])
    assert schema["ChannelRequest"]["properties"]["receivers"]["anyOf"][0]["maxItems"] == 4
    assert schema["Band"]["properties"]["points"]["maximum"] == 11
    for name in ("ToaRequest", "PdoaRequest", "RssRequest"):
        assert schema[name]["properties"]["trials"]["maximum"] == 20
    # the committed openapi.json keeps the hard ceilings (default settings)
    assert create_app(make_settings(max_rays=10**6)).openapi()["components"]["schemas"]["ChannelRequest"][
        "properties"]["rays"]["anyOf"][0]["maximum"] == 10**6


def test_a_phantom_stored_with_a_kindless_site_in_tissue_still_loads(make_settings, glb_phantom):
    """Uploads stored before kinds were required inside tissue keep the kind they were stored with."""
    settings = make_settings()
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        pid = upload(client, *glb_phantom()).json()["id"]
        manifest_file = settings.data_dir / "phantoms" / pid / "manifest.json"
        old = json.loads(manifest_file.read_text())
        old["sites"]["capsule"] = old["sites"]["capsule"]["position_m"]  # the old bare-list form
        manifest_file.write_text(json.dumps(old))
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:  # a restart
        r = client.post("/v1/channel", json={"phantom": pid, "transmitter": {"site": "capsule"},
                                              "receivers": [{"site": "sensor"}], "rays": 500, "max_interactions": 1})
        assert r.status_code == 200, r.text
        manifest = client.get(f"/v1/phantoms/{pid}/manifest").json()
        assert manifest["sites"]["capsule"]["kind"] == "capsule"  # re-uploads as the same phantom


def _actions(parser: argparse.ArgumentParser, path: str = "capsule-rt"):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _actions(sub, f"{path} {name}")
        elif not isinstance(action, argparse._HelpAction):
            yield path, action


def test_every_cli_option_and_command_has_help():
    parser = build_parser()
    missing = [f"{path} {action.dest}" for path, action in _actions(parser)
               if not action.help or action.help == argparse.SUPPRESS]
    assert missing == []
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert all(choice.help for choice in commands._choices_actions)


def test_demo_traces_with_the_apis_default_rays(monkeypatch, capsys):
    import service.cli as cli

    sent = []
    monkeypatch.setattr(cli, "_demo_case", lambda title, payload: sent.append(payload))
    assert cli.main(["demo"]) == 0
    assert sent and all("rays" not in payload for payload in sent)
    sent.clear()
    assert cli.main(["demo", "--rays", "3000"]) == 0
    assert all(payload["rays"] == 3000 for payload in sent)
