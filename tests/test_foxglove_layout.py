"""The shipped Foxglove layouts: each is the one the generator builds for its plant, and every
topic, field path and frame it names exists in a real log of that plant (its channels, their
protobuf schemas, the decoded messages); a path the log lacks is reported (the check can fail)."""

import json

import pytest
from google.protobuf import descriptor_pb2
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from conftest import ROOT
from ftstab_mj.logs.foxglove_layout import SHIPPED, layout_json, shipped_path


def _references(node, out=None) -> dict:
    """{"paths": message paths of the plots, "topics": topics of the other panels, "frames": frames}."""
    out = out if out is not None else {"paths": [], "topics": [], "frames": []}
    if isinstance(node, dict):
        kind, config = node.get("panelType"), node.get("config") or {}
        if kind == "Plot":
            out["paths"] += [p["value"] for p in config["paths"]]
        elif kind == "RawMessages":
            out["topics"].append(config["topicPath"])
        elif kind == "ThreeDee":
            out["topics"] += list(config.get("topics", {}))
            out["frames"] += [config[k] for k in ("fixedFrame", "followTf") if k in config]
        for value in node.values():
            _references(value, out)
    elif isinstance(node, list):
        for value in node:
            _references(value, out)
    return out


def _log_content(path):
    """({topic: (schema name, {field: repeated?})}, {topic: first decoded message}, frames of /tf),
    read with the plain mcap reader (protobuf through mcap-protobuf-support, JSON through json)."""
    from mcap.decoder import DecoderFactory as Base

    class JsonFactory(Base):
        def decoder_for(self, message_encoding, schema):
            return json.loads if message_encoding == "json" else None

    channels, first, frames = {}, {}, set()
    with open(path, "rb") as f:
        for schema, channel, message, decoded in make_reader(
                f, decoder_factories=[DecoderFactory(), JsonFactory()]).iter_decoded_messages():
            if channel.topic not in channels:
                fields = {}
                if schema.encoding == "protobuf":
                    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
                    for fd in fds.file:
                        for m in fd.message_type:
                            if f"{fd.package}.{m.name}" == schema.name:
                                fields = {x.name: x.label == x.LABEL_REPEATED for x in m.field}
                channels[channel.topic] = (schema.name, fields)
                first[channel.topic] = decoded
            if channel.topic == "/tf":
                frames |= {t.parent_frame_id for t in decoded.transforms} | {t.child_frame_id for t in decoded.transforms}
    return channels, first, frames


def layout_problems(layout: dict, log) -> list[str]:
    """What ``layout`` names that the log at ``log`` does not have (empty: everything is there)."""
    channels, first, frames = _log_content(log)
    refs, problems = _references(layout), []
    for path in refs["paths"]:
        topic, _, field = path.partition(".")
        name, _, index = field.partition("[")
        if topic not in channels:
            problems.append(f"{path}: no channel {topic}")
        elif name not in channels[topic][1]:
            problems.append(f"{path}: {channels[topic][0]} has no field {name}")
        elif index:
            i = int(index.rstrip("]"))
            if not channels[topic][1][name] or i >= len(getattr(first[topic], name)):
                problems.append(f"{path}: {name} has no element {i}")
        elif channels[topic][1][name]:
            problems.append(f"{path}: {name} is repeated (a plot needs one value)")
    problems += [f"{t}: no channel" for t in refs["topics"] if t not in channels]
    if "/scene" in refs["topics"] and channels.get("/scene", ("",))[0] != "foxglove.SceneUpdate":
        problems.append("/scene: not a foxglove.SceneUpdate channel")
    problems += [f"frame {fr}: not in /tf" for fr in refs["frames"] if fr not in frames]
    return problems


def _scenario_of(plant: str) -> str:
    """A shipped scenario on ``plant`` (the first by file name)."""
    import tomllib

    for path in sorted((ROOT / "scenarios").glob("*.toml")):
        if tomllib.loads(path.read_text())["plant"]["model"] == plant:
            return path.stem
    raise AssertionError(f"no shipped scenario on {plant}")


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """{plant: a short real log of a shipped scenario on it}."""
    import ftstab_mj

    out = tmp_path_factory.mktemp("layout_logs")
    return {plant: ftstab_mj.run(_scenario_of(plant), out=out / plant, overrides={"sim.duration": 0.05}).logs["mcap"]
            for plant in SHIPPED}


@pytest.mark.parametrize("plant", sorted(SHIPPED))
def test_every_path_the_shipped_layout_names_exists_in_a_real_log(plant, logs):
    text = shipped_path(plant).read_text()
    assert text == layout_json(SHIPPED[plant]), "the shipped file is out of date: python -m ftstab_mj.logs.foxglove_layout --shipped"
    layout = json.loads(text)
    refs = _references(layout)
    loops = SHIPPED[plant]
    assert len(refs["paths"]) == sum(r + 3 for _, r in loops)  # z_1..z_r, u, u0, V1 per loop
    assert refs["topics"] == ["/scene", "/metrics"] and refs["frames"] == ["world", "world"]
    assert layout_problems(layout, logs[plant]) == []


def test_the_check_reports_what_a_log_lacks(logs):
    """The r = 3 cart layout on an r = 2 log names z[2], which it lacks; the arm's names loops it lacks."""
    three = json.loads(shipped_path("cart_integrating").read_text())
    assert layout_problems(three, logs["cart"]) == ["/loop/cart.z[2]: z has no element 2"]
    arm = json.loads(shipped_path("arm").read_text())
    assert "/loop/joint0.u: no channel /loop/joint0" in layout_problems(arm, logs["cart"])


def test_a_layout_for_any_log(tmp_path, logs):
    """python -m ftstab_mj.logs.foxglove_layout LOG OUT writes the layout of that log's loops."""
    import subprocess
    import sys

    out = tmp_path / "layout.json"
    done = subprocess.run([sys.executable, "-m", "ftstab_mj.logs.foxglove_layout", str(logs["arm3"]), str(out)],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    assert out.read_text() == shipped_path("arm3").read_text()
    bad = subprocess.run([sys.executable, "-m", "ftstab_mj.logs.foxglove_layout", str(tmp_path / "none.mcap"), str(out)],
                         capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert bad.returncode == 2 and bad.stderr.startswith("error: ") and "Traceback" not in bad.stderr
