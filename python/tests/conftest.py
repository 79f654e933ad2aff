"""Where the tests find the workspace's release binaries (`cabc-sim`, `learner`, `cabc`): $CABC_BIN_DIR, by default
target/release of the repository (deploy/test.sh builds them first). A missing binary fails the test that needs it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def bin_dir() -> Path:
    return Path(os.environ.get("CABC_BIN_DIR", ROOT / "target" / "release"))


def binary(bin_dir: Path, name: str) -> Path:
    path = bin_dir / name
    if not path.is_file():
        pytest.fail(f"{path} is missing: build the workspace's binaries first (cargo build --release --workspace --bins)")
    return path
