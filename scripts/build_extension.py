"""Build the RSTrace Blender extension: dist/rstrace-<version>-<platform>.zip.

Stages ``addon/`` (the extension's package) with ``blender_manifest.toml`` and a ``wheels/``
folder: the ``rstrace_engine`` wheel (``pip wheel . --no-deps``) and the numba and llvmlite
wheels for each platform (``pip download --only-binary=:all: --platform ... --python-version
3.11``, pinned to the versions installed here), then runs Blender's own
``blender_ext.py build --split-platforms``. Platforms other than ``linux-x64`` are optional:
if their wheels cannot be downloaded they are left out with a warning.

    python scripts/build_extension.py [--platforms linux-x64 windows-x64 macos-arm64]
                                      [--out dist] [--stage build/extension]
                                      [--wheel-cache build/wheel-cache]
"""

from __future__ import annotations

import argparse
import glob
import importlib.metadata
import importlib.util
import logging
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PYTHON_VERSION = "3.11"  # Blender 4.2 - 5.x
REQUIRED = ("linux-x64",)
#: Blender platform -> pip --platform tag (pip also accepts older manylinux/macOS tags).
PIP_PLATFORMS = {
    "linux-x64": "manylinux_2_28_x86_64",
    "windows-x64": "win_amd64",
    "macos-arm64": "macosx_14_0_arm64",
}
DEPENDENCIES = ("numba", "llvmlite")


_log = logging.getLogger("build_extension")


def log(msg: str) -> None:
    _log.info(msg)


def run(cmd: list[str], **kw) -> subprocess.CompletedProcess:
    log(" ".join(str(c) for c in cmd))
    return subprocess.run([str(c) for c in cmd], check=True, **kw)


def engine_version() -> str:
    text = (ROOT / "rstrace_engine" / "__init__.py").read_text()
    m = re.search(r'^__version__\s*=\s*"([^"]+)"', text, re.M)
    if not m:
        raise SystemExit("cannot find __version__ in rstrace_engine/__init__.py")
    return m.group(1)


def blender_ext_script() -> Path:
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("the bpy module is needed for Blender's blender_ext.py build tool")
    base = Path(list(spec.submodule_search_locations)[0])
    found = sorted(glob.glob(str(base / "*" / "scripts" / "addons_core" / "bl_pkg" / "cli"
                                / "blender_ext.py")))
    if not found:
        raise SystemExit(f"blender_ext.py not found under {base}")
    return Path(found[-1])


def stage_addon(stage: Path) -> None:
    if stage.exists():
        shutil.rmtree(stage)
    shutil.copytree(ROOT / "addon", stage,
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    (stage / "wheels").mkdir()


def engine_wheel(stage: Path, version: str) -> Path:
    out = stage / "wheels"
    run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "-q", "-w", out])
    wheel = out / f"rstrace_engine-{version}-py3-none-any.whl"
    if not wheel.exists():
        raise SystemExit(f"expected {wheel.name}, got {[p.name for p in out.iterdir()]}")
    return wheel


def dependency_wheels(platform: str, cache: Path) -> list[Path]:
    """numba and llvmlite wheels for ``platform`` (downloaded once into ``cache``)."""
    tag = PIP_PLATFORMS[platform]
    pins = [f"{name}=={importlib.metadata.version(name)}" for name in DEPENDENCIES]
    target = cache / platform
    target.mkdir(parents=True, exist_ok=True)
    wheels = _matching(target, pins)
    if len(wheels) < len(pins):
        run([sys.executable, "-m", "pip", "download", "--only-binary=:all:", "--no-deps",
             "--platform", tag, "--python-version", PYTHON_VERSION, "-q", "-d", target,
             *pins])
        wheels = _matching(target, pins)
    if len(wheels) != len(pins):
        raise RuntimeError(f"{platform}: expected wheels for {pins}, found "
                           f"{[w.name for w in wheels]}")
    return wheels


def _matching(folder: Path, pins: list[str]) -> list[Path]:
    out = []
    for pin in pins:
        name, version = pin.split("==")
        hits = sorted(folder.glob(f"{name}-{version}-*.whl"))
        if hits:
            out.append(hits[-1])
    return out


def write_manifest(stage: Path, version: str, platforms: list[str], wheels: list[Path]):
    text = (ROOT / "blender_manifest.toml").read_text()
    text, n1 = re.subn(r'^version = ".*"$', f'version = "{version}"', text, flags=re.M)
    plat = ", ".join(f'"{p}"' for p in platforms)
    text, n2 = re.subn(r"^platforms = \[.*?\]$", f"platforms = [{plat}]", text,
                       flags=re.M | re.S)
    listed = "\n".join(f'  "./wheels/{w.name}",' for w in wheels)
    text, n3 = re.subn(r"^wheels = \[.*?^\]$", f"wheels = [\n{listed}\n]", text,
                       flags=re.M | re.S)
    if (n1, n2, n3) != (1, 1, 1):
        raise SystemExit("blender_manifest.toml: could not find version/platforms/wheels")
    (stage / "blender_manifest.toml").write_text(text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--platforms", nargs="+", default=list(PIP_PLATFORMS),
                    choices=list(PIP_PLATFORMS))
    ap.add_argument("--out", type=Path, default=ROOT / "dist")
    ap.add_argument("--stage", type=Path, default=ROOT / "build" / "extension")
    ap.add_argument("--wheel-cache", type=Path, default=ROOT / "build" / "wheel-cache")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="build_extension: %(message)s")

    version = engine_version()
    stage = args.stage.resolve()
    stage_addon(stage)
    wheels = [engine_wheel(stage, version)]
    platforms = []
    for platform in args.platforms:
        try:
            deps = dependency_wheels(platform, args.wheel_cache.resolve())
        except (subprocess.CalledProcessError, RuntimeError) as exc:
            if platform in REQUIRED:
                raise SystemExit(f"{platform}: cannot get numba/llvmlite wheels ({exc})") from exc
            log(f"warning: {platform} left out, no wheels ({exc})")
            continue
        for w in deps:
            shutil.copy2(w, stage / "wheels" / w.name)
            wheels.append(stage / "wheels" / w.name)
        platforms.append(platform)
    write_manifest(stage, version, platforms, wheels)

    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob(f"rstrace-{version}-*.zip"):
        if old.name.rsplit("-", 1)[-1][:-4].replace("_", "-") in platforms:
            old.unlink()
    run([sys.executable, blender_ext_script(), "build", "--source-dir", stage,
         "--output-dir", out, "--split-platforms"])
    built = sorted(out.glob(f"rstrace-{version}-*.zip"))
    for z in built:
        log(f"built {z.relative_to(ROOT) if z.is_relative_to(ROOT) else z} "
            f"({z.stat().st_size / 2**20:.1f} MiB)")
    missing = [p for p in platforms
               if not (out / f"rstrace-{version}-{p.replace('-', '_')}.zip").exists()]
    if missing:
        raise SystemExit(f"no zip built for {missing}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
