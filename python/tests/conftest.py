"""Fixtures of the shimmy_monitor test suite.

Run by tests/python_package.rs (``cargo test --release --test python_package``), which builds the
wheel, installs it into target/py-venv and sets:

* ``SHIMMY_BIN``: the ``shimmy`` CLI the package's results are compared with;
* ``FIRMWARE_SIM_BIN``: the simulator that writes vehicle logs with a known clearance;
* ``SHIMMY_DATA_DIR``: the shared real logs and DBCs (absent: those tests skip, but fail under
  ``CI=true``).
"""

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

IN_CI = os.environ.get("CI") in ("true", "1")
REPO = Path(__file__).resolve().parents[2]


def _need_env(name: str) -> Path:
    v = os.environ.get(name)
    if not v or not Path(v).exists():
        msg = f"{name} not set or missing ({v!r}); run through tests/python_package.rs"
        if IN_CI:
            pytest.fail(msg)
        pytest.skip(msg)
    return Path(v)


@pytest.fixture(scope="session")
def shimmy_bin() -> Path:
    return _need_env("SHIMMY_BIN")


@pytest.fixture(scope="session")
def firmware_sim_bin() -> Path:
    return _need_env("FIRMWARE_SIM_BIN")


@pytest.fixture(scope="session")
def data_dir() -> Path:
    d = Path(os.environ.get("SHIMMY_DATA_DIR", REPO.parent / "shared" / "data"))
    if not d.is_dir():
        msg = f"shared test data not found at {d} (set SHIMMY_DATA_DIR)"
        if IN_CI:
            pytest.fail(msg)
        pytest.skip(msg)
    return d


def run_cli(shimmy_bin: Path, *args, check=True) -> subprocess.CompletedProcess:
    """Runs the CLI from the repository root (where it finds config/vehicles)."""
    p = subprocess.run(
        [str(shimmy_bin), *map(str, args)], cwd=REPO, capture_output=True, text=True
    )
    if check and p.returncode != 0:
        raise AssertionError(f"shimmy {' '.join(map(str, args))} failed: {p.stderr}")
    return p


def cli_estimate(shimmy_bin: Path, profile: str, logs) -> dict:
    out = run_cli(shimmy_bin, "estimate", "--profile", profile, "--format", "json", *logs)
    return json.loads(out.stdout)


@pytest.fixture(scope="session")
def sim_logs(firmware_sim_bin, tmp_path_factory) -> list:
    """Three simulated RAV4 drives (candump), 4 braking events each, seeds 7100..7102."""
    d = tmp_path_factory.mktemp("sim")
    subprocess.run(
        [str(firmware_sim_bin), "fleet", "--profile", "toyota_rav4", "--vehicles", "3",
         "--events", "4", "--seed-base", "7100", "--logs-only", "--work-dir", str(d),
         "--threads", "2"],
        cwd=REPO, check=True, capture_output=True,
    )
    return sorted(d.glob("fleet_*.log"))


@pytest.fixture(scope="session")
def fleet(firmware_sim_bin, tmp_path_factory):
    """A simulated fleet of 22 RAV4s (3 braking events each; seeds 6000..6021), as a manifest:

    * vehicles ``car-00`` .. ``car-19``: one log each, except ``car-00``..``car-02`` whose drive
      is split into two logs (so a vehicle's logs are fed in order);
    * ``car-corrupt``: a good drive (seed 6020) and a corrupt log after it;
    * ``car-unknown``: a good drive (seed 6021) under a profile that does not exist.
    """
    d = tmp_path_factory.mktemp("fleet")
    sim = d / "sim"
    subprocess.run(
        [str(firmware_sim_bin), "fleet", "--profile", "toyota_rav4", "--vehicles", "22",
         "--events", "3", "--seed-base", "6000", "--logs-only", "--work-dir", str(sim),
         "--threads", "2"],
        cwd=REPO, check=True, capture_output=True,
    )
    manifest = []
    logs = d / "logs"
    for k in range(20):
        v = f"car-{k:02d}"
        (logs / v).mkdir(parents=True)
        src = sim / f"fleet_{6000 + k}.log"
        if k < 3:
            lines = src.read_bytes().splitlines(keepends=True)
            half = len(lines) // 2
            a, b = logs / v / "a.log", logs / v / "b.log"
            a.write_bytes(b"".join(lines[:half]))
            b.write_bytes(b"".join(lines[half:]))
            parts = [a, b]
        else:
            parts = [logs / v / "drive.log"]
            shutil.copy(src, parts[0])
        manifest += [dict(vehicle=v, profile="toyota_rav4", log=str(p)) for p in parts]
    (logs / "car-corrupt").mkdir()
    good = logs / "car-corrupt" / "a.log"
    shutil.copy(sim / "fleet_6020.log", good)
    bad = logs / "car-corrupt" / "b.blf"
    bad.write_bytes(b"LOGG" + bytes(range(256)) * 8)
    manifest += [
        dict(vehicle="car-corrupt", profile="toyota_rav4", log=str(good)),
        dict(vehicle="car-corrupt", profile="toyota_rav4", log=str(bad)),
    ]
    (logs / "car-unknown").mkdir()
    unk = logs / "car-unknown" / "drive.log"
    shutil.copy(sim / "fleet_6021.log", unk)
    manifest.append(dict(vehicle="car-unknown", profile="no_such_car", log=str(unk)))
    path = d / "manifest.csv"
    with open(path, "w") as f:
        f.write("vehicle,profile,log\n")
        for r in manifest:
            f.write(f"{r['vehicle']},{r['profile']},{r['log']}\n")
    return dict(dir=d, manifest=path, rows=manifest, corrupt=bad, unknown=unk)


@pytest.fixture(scope="session")
def new_joints(firmware_sim_bin, tmp_path_factory):
    """Five simulated RAV4s at new joints (0.03 mm; 6 braking events each; seeds 7300..7304),
    one folder per vehicle (``nj-0`` .. ``nj-4``; ``nj-0``'s drive split into two logs), and
    their manifest rows; for the car model's correction (``shimmy fleet-fit``)."""
    d = tmp_path_factory.mktemp("new_joints")
    sim = d / "sim"
    subprocess.run(
        [str(firmware_sim_bin), "fleet", "--profile", "toyota_rav4", "--vehicles", "5",
         "--events", "6", "--seed-base", "7300", "--clearance-mm", "0.03", "--logs-only",
         "--work-dir", str(sim), "--threads", "2"],
        cwd=REPO, check=True, capture_output=True,
    )
    dirs, manifest = [], []
    for k in range(5):
        v = d / f"nj-{k}"
        v.mkdir()
        src = sim / f"fleet_{7300 + k}.log"
        if k == 0:
            lines = src.read_bytes().splitlines(keepends=True)
            (v / "a.log").write_bytes(b"".join(lines[: len(lines) // 2]))
            (v / "b.log").write_bytes(b"".join(lines[len(lines) // 2 :]))
        else:
            shutil.copy(src, v / "drive.log")
        dirs.append(v)
        for p in sorted(v.iterdir()):
            manifest.append(dict(vehicle=v.name, profile="toyota_rav4", log=str(p),
                                 seq=str(len(manifest))))
    return dict(dir=d, vehicles=dirs, manifest=manifest)
