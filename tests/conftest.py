"""Shared test fixtures: paths to the third-party assets in ../shared (skip when absent)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

# Under pytest-xdist (README's test command runs one worker per core) each worker gets an equal
# share of the cores for torch and for the subprocesses it starts, so that the workers do not
# oversubscribe a 2-core machine with torch threads.
if os.environ.get("PYTEST_XDIST_WORKER"):
    _share = max(1, (os.cpu_count() or 1) // max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))))
    os.environ.setdefault("OMP_NUM_THREADS", str(_share))
    torch.set_num_threads(_share)

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
MTLX_RES = SHARED / "assets" / "materialx" / "resources"
USD_ASSETS = SHARED / "assets" / "usd" / "test_assets"


if (SHARED / "assets" / "materialx").exists():
    # MaterialX's test files name some textures relative to the MaterialX repository
    # root, which MaterialX's own test runner puts on MATERIALX_SEARCH_PATH.
    os.environ.setdefault("MATERIALX_SEARCH_PATH", str(SHARED / "assets" / "materialx"))


from materials import SIMPLE_MTLX  # noqa: E402,F401  (re-exported: tests import it from conftest)


def shared_path(*parts) -> Path:
    """A path under ../shared/assets, or skip the test when ../shared is absent."""
    p = SHARED.joinpath("assets", *parts)
    if not p.exists():
        pytest.skip(f"../shared asset not available: {p}")
    return p


def random_dirs(n: int, seed: int, upper: bool = True) -> torch.Tensor:
    """``n`` seeded unit vectors, uniform on the (upper) sphere."""
    g = torch.Generator().manual_seed(seed)
    v = torch.randn(n, 3, generator=g, dtype=torch.float64)
    v = v / v.norm(dim=1, keepdim=True)
    if upper:
        v[:, 2] = v[:, 2].abs()
    return v.float()


def write_float_image(path, img) -> None:
    """Write a float32 ``[H, W, C]`` array (row 0 = top) with OpenImageIO."""
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(img.shape[1], img.shape[0], img.shape[2], "float"))
    out.write_image(img)
    out.close()


def unprivileged_prefix(tmp_path: Path) -> list[str]:
    """A command prefix under which file permissions apply (chmod 000 denies reads, 0555 denies
    writes); skips the test when there is none.

    As root, file permissions do not apply; ``setpriv`` drops the capabilities that
    bypass them (CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH) for the child process.
    """
    prefix: list[str] = []
    if os.geteuid() == 0:
        setpriv = shutil.which("setpriv")
        if setpriv is None:
            pytest.skip("running as root, and setpriv (to drop CAP_DAC_OVERRIDE) is not available")
        prefix = [setpriv, "--bounding-set=-dac_override,-dac_read_search", "--"]
    probe = tmp_path / "probe"
    probe.write_text("x")
    probe.chmod(0)
    try:
        r = subprocess.run([*prefix, sys.executable, "-c", f"open({str(probe)!r}).read()"],
                           capture_output=True, text=True, timeout=60, check=False)
    except OSError as exc:
        pytest.skip(f"cannot run a process without file-permission override: {exc}")
    finally:
        probe.unlink()
    if "PermissionError" not in r.stderr:
        pytest.skip("file permissions are not enforced for this user (root without a way to drop "
                    f"CAP_DAC_OVERRIDE): {r.stderr.strip()[-200:]}")
    return prefix
