"""`cabc export` of a smoke run, read back with pyarrow: the LeRobot v3 layout, a row per step the replay holds
(counted against the run's summary.json), episodes, versions, images, and errors that name what is wrong."""

from __future__ import annotations

import json
import struct
import subprocess
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from conftest import binary

# The learner's presets (state, and 32x32 camera images).
CONFIGS = {"state": "smoke", "camera": "smoke-camera"}


@pytest.fixture(scope="module", params=sorted(CONFIGS))
def exported(request, bin_dir, tmp_path_factory):
    """A fresh `learner run --local --config smoke[-camera]` (seconds) and its `cabc export`."""
    learner, cabc = binary(bin_dir, "learner"), binary(bin_dir, "cabc")
    tmp = tmp_path_factory.mktemp(request.param)
    run, out = tmp / "run", tmp / "dataset"
    subprocess.run(
        [learner, "run", "--local", "--config", CONFIGS[request.param], "--run-dir", run],
        check=True, capture_output=True,
    )
    done = subprocess.run([cabc, "export", run, "--out", out], check=True, capture_output=True, text=True)
    return request.param, run, out, json.loads(done.stdout)


def test_the_layout_is_lerobot_v3(exported):
    kind, _, out, report = exported
    for path in ["data/chunk-000/file-000.parquet", "meta/info.json", "meta/stats.json", "meta/tasks.parquet",
                 "meta/episodes/chunk-000/file-000.parquet"]:
        assert (out / path).is_file(), path
    info = json.loads((out / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == 10
    assert info["total_frames"] == report["frames"] and info["total_episodes"] == report["episodes"]
    features = info["features"]
    assert features["observation.state"] == {
        "dtype": "float32", "shape": [6], "names": ["v_long", "v_tran", "omega", "s", "x_tran", "e_psi"]}
    assert features["action"]["shape"] == [2] and features["next.observation.state"]["shape"] == [6]
    assert ("observation.image" in features) == (kind == "camera")
    stats = json.loads((out / "meta/stats.json").read_text())
    assert stats["action"]["count"] == [report["frames"]]
    assert len(stats["observation.state"]["mean"]) == 6


def test_rows_are_the_runs_stored_steps(exported):
    _, run, out, report = exported
    summary = json.loads((run / "summary.json").read_text())
    table = pq.read_table(out / "data/chunk-000/file-000.parquet")
    stores = table.column("store").to_pylist()
    count = {s: stores.count(s) for s in ("D+", "D?", "D-", "dynamics-only")}
    # A smoke run evicts nothing: every step it stored is a row.
    assert table.num_rows == report["frames"] == summary["steps_stored"]
    assert count["D+"] == summary["d_plus"]
    assert count["D?"] + count["D-"] == summary["d_uncertain"]
    assert count["D-"] == summary["d_minus"]
    assert report["versions_known"] == [True, True, True]
    versions = np.array(table.column("policy_version").to_pylist())
    assert versions.min() == 0 and versions.max() <= summary["epochs"] - 1
    state = np.array(table.column("observation.state").to_pylist(), dtype=np.float32)
    velocity = np.array(table.column("observation.velocity").to_pylist(), dtype=np.float32)
    assert state.shape == (table.num_rows, 6)
    np.testing.assert_array_equal(velocity, state[:, :3])


def test_episodes_are_chains_of_steps(exported):
    _, _, out, report = exported
    table = pq.read_table(out / "data/chunk-000/file-000.parquet")
    episodes = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert len(episodes) == report["episodes"]
    assert sum(e["length"] for e in episodes) == table.num_rows
    state = np.array(table.column("observation.state").to_pylist())
    nxt = np.array(table.column("next.observation.state").to_pylist())
    index = table.column("episode_index").to_pylist()
    frame = table.column("frame_index").to_pylist()
    stamp = table.column("timestamp").to_pylist()
    for e in episodes:
        lo, hi = e["dataset_from_index"], e["dataset_to_index"]
        assert hi - lo == e["length"] and set(index[lo:hi]) == {e["episode_index"]}
        assert frame[lo:hi] == list(range(e["length"]))
        assert stamp[lo:hi] == pytest.approx([k / 10 for k in range(e["length"])])
        # Within an episode each state is the previous step's next state.
        np.testing.assert_array_equal(state[lo + 1:hi], nxt[lo:hi - 1])


def png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


def test_images_are_pngs_where_the_run_keeps_them(exported, bin_dir):
    kind, _, out, _ = exported
    table = pq.read_table(out / "data/chunk-000/file-000.parquet")
    if kind == "state":
        assert "observation.image" not in table.column_names
        return
    images = table.column("observation.image").to_pylist()
    stores = table.column("store").to_pylist()
    for image, store in zip(images, stores):
        assert (image is not None) == (store == "D+")
        if image is not None:
            assert png_size(image["bytes"]) == (32, 32) and image["path"] is None


def test_bad_runs_and_outputs_are_refused(bin_dir, tmp_path, exported):
    cabc = binary(bin_dir, "cabc")
    _, run, out, _ = exported
    for args, message in [
        ([tmp_path / "nowhere", "--out", tmp_path / "a"], "not a run folder"),
        ([tmp_path, "--out", tmp_path / "b"], "config.toml"),
        ([run, "--out", out], "not empty"),
    ]:
        done = subprocess.run([cabc, "export", *args], capture_output=True, text=True)
        assert done.returncode != 0 and message in done.stderr, done.stderr
