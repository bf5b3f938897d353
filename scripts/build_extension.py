"""Build the RSTrace Blender extension: dist/rstrace-<version>-<platform>.zip.

Stages ``addon/`` (the extension's package) with ``blender_manifest.toml`` and a ``wheels/``
folder: the ``rstrace_engine`` wheel (``pip wheel . --no-deps``) and the numba and llvmlite
wheels for each platform (``pip download --only-binary=:all: --platform ... --python-version
3.11``, pinned to the versions installed here), then runs Blender's own
``blender_ext.py build --split-platforms``, one platform at a time (each zip has its own
stage). Platforms other than ``linux-x64`` are optional: if their wheels cannot be downloaded
they are left out with a warning.

Compiled kernels: for the platform this machine is (linux-x64 here), every render kernel is
compiled for numba's portable CPU (``NUMBA_CPU_NAME=generic``) by ``python -m rstrace_engine
warm-cache`` (in parallel) into ``build/kernel-cache/<platform>`` (kept between builds: the
cache is keyed on the sources' contents, so only what changed compiles again), and the
current entries are packed into the zip's ``kernel_cache/`` with a manifest
(``rstrace-kernels.json``: platform, CPU, numba/llvmlite/Python/engine versions). The other
platforms' zips carry a manifest that says no compiled kernels ship (they compile on first
use). ``--no-kernels`` skips the compile (every zip then says so).

    python scripts/build_extension.py [--platforms linux-x64 windows-x64 macos-arm64]
                                      [--out dist] [--stage build/extension]
                                      [--wheel-cache build/wheel-cache]
                                      [--kernel-cache build/kernel-cache] [--no-kernels]
"""

from __future__ import annotations

import argparse
import glob
import importlib.metadata
import importlib.util
import json
import logging
import os
import platform as _platform
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


def host_platform() -> str | None:
    """The Blender platform name of this machine, when it is one we build for."""
    machine = _platform.machine().lower()
    system = _platform.system()
    if system == "Linux" and machine in ("x86_64", "amd64"):
        return "linux-x64"
    if system == "Windows" and machine in ("x86_64", "amd64"):
        return "windows-x64"
    if system == "Darwin" and machine in ("arm64", "aarch64"):
        return "macos-arm64"
    return None


def compile_kernels(cache: Path) -> dict:
    """Every render kernel for numba's portable CPU into ``cache`` (a subprocess per core)."""
    cache.mkdir(parents=True, exist_ok=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update(NUMBA_CACHE_DIR=str(cache), NUMBA_CPU_NAME="generic", NUMBA_CPU_FEATURES="",
               PYTHONPATH=str(ROOT))
    proc = run([sys.executable, "-m", "rstrace_engine", "warm-cache", "--json"], cwd=ROOT,
               env=env, capture_output=True, text=True)
    result = json.loads(proc.stdout)
    log(f"kernels for the generic CPU: {result['compiled']} compiled, {result['loaded']} "
        f"loaded in {result['seconds']:.0f} s ({result.get('jobs', 1)} processes)")
    if result["unreached"]:
        log("warning: kernels no warm-up step reached: " + ", ".join(result["unreached"]))
    return result


def pack_kernels(stage: Path, platform: str, cache: Path | None, why: str) -> dict:
    """``stage/kernel_cache``: the current entries of ``cache`` and the manifest."""
    sys.path.insert(0, str(ROOT))
    from rstrace_engine import kernel_cache, shipped_kernels

    folder = stage / "kernel_cache"
    folder.mkdir()
    counts = {}
    if cache is not None:
        counts = shipped_kernels.seed(str(cache), str(folder))
        for lock in folder.rglob(kernel_cache.LOCK_NAME):
            lock.unlink()
    manifest = shipped_kernels.build_manifest(platform, cache is not None, why)
    if cache is not None:
        manifest["cpu"] = "generic"
    manifest["kernels"] = counts.get("kernels", 0)
    manifest["signatures"] = counts.get("copied", 0)
    (folder / shipped_kernels.MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
    if cache is None:
        (folder / "README.txt").write_text(
            f"No compiled kernels ship for {platform}: {why}.\nRSTrace compiles its kernels "
            "on first use (a few minutes on two cores; the status bar shows the progress).\n")
    return manifest


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--platforms", nargs="+", default=list(PIP_PLATFORMS),
                    choices=list(PIP_PLATFORMS))
    ap.add_argument("--out", type=Path, default=ROOT / "dist")
    ap.add_argument("--stage", type=Path, default=ROOT / "build" / "extension")
    ap.add_argument("--wheel-cache", type=Path, default=ROOT / "build" / "wheel-cache")
    ap.add_argument("--kernel-cache", type=Path, default=ROOT / "build" / "kernel-cache")
    ap.add_argument("--no-kernels", action="store_true",
                    help="ship no compiled kernels (they compile on first use)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="build_extension: %(message)s")

    version = engine_version()
    host = host_platform()
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    built = []
    compiled = None
    for platform in args.platforms:
        try:
            deps = dependency_wheels(platform, args.wheel_cache.resolve())
        except (subprocess.CalledProcessError, RuntimeError) as exc:
            if platform in REQUIRED:
                raise SystemExit(f"{platform}: cannot get numba/llvmlite wheels ({exc})") from exc
            log(f"warning: {platform} left out, no wheels ({exc})")
            continue
        stage = args.stage.resolve() / platform
        stage_addon(stage)
        wheels = [engine_wheel(stage, version)]
        for w in deps:
            shutil.copy2(w, stage / "wheels" / w.name)
            wheels.append(stage / "wheels" / w.name)
        write_manifest(stage, version, [platform], wheels)
        cache, why = None, ""
        if args.no_kernels:
            why = "built with --no-kernels"
        elif platform != host:
            why = f"built on {host or _platform.platform()}, which cannot compile for {platform}"
        else:
            cache = (args.kernel_cache.resolve() / platform)
            if compiled is None:
                compiled = compile_kernels(cache)
        manifest = pack_kernels(stage, platform, cache, why)
        name = f"rstrace-{version}-{platform.replace('-', '_')}.zip"
        (out / name).unlink(missing_ok=True)
        run([sys.executable, blender_ext_script(), "build", "--source-dir", stage,
             "--output-dir", out, "--split-platforms"])
        if not (out / name).exists():
            raise SystemExit(f"no zip built for {platform}")
        built.append((out / name, manifest))
    for z, manifest in built:
        kernels = (f"{manifest['signatures']} compiled kernel signatures for the generic CPU"
                   if manifest["shipped"] else f"no compiled kernels ({manifest['reason']})")
        log(f"built {z.relative_to(ROOT) if z.is_relative_to(ROOT) else z} "
            f"({z.stat().st_size / 2**20:.1f} MiB, {kernels})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
