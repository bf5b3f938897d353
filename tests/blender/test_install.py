"""The extension zip installs into a fresh Blender user directory, renders, uninstalls.

Runs in a fresh subprocess (``BLENDER_USER_RESOURCES`` must be set before ``bpy`` starts,
and the repository must not shadow the installed ``rstrace_engine`` wheel). The zip is
built for linux-x64 by ``scripts/build_extension.py`` into a temporary folder (a few
seconds once the numba/llvmlite wheels are in ``build/wheel-cache``); without network and
cache, an existing ``dist/rstrace-*-linux_x64.zip`` from ``make extension`` is used.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = textwrap.dedent('''
    import json, os, sys, time

    zip_path, out_dir, repo = sys.argv[1], sys.argv[2], os.path.realpath(sys.argv[3])
    # A user's Blender has no checkout: hide the repository (a path entry, or the finder of
    # an editable install from `make`) so that rstrace_engine must come from the wheel.
    sys.path[:] = [p for p in sys.path if os.path.realpath(p or ".") != repo]
    sys.meta_path[:] = [f for f in sys.meta_path
                        if not getattr(f, "__module__", "").startswith("__editable__")]
    import bpy

    result = {}
    t0 = time.perf_counter()
    bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                             enable_on_install=True)
    result["install_s"] = time.perf_counter() - t0
    result["enabled"] = "bl_ext.user_default.rstrace" in bpy.context.preferences.addons
    # the farm's warm-up step (docs/FARM.md) is registered by the installed extension
    result["warm_cache_operator"] = "warm_cache" in dir(bpy.ops.rstrace)
    import numba
    import rstrace_engine
    result["engine_file"] = rstrace_engine.__file__
    result["cache_dir"] = numba.config.CACHE_DIR
    result["expected_cache_dir"] = bpy.utils.extension_path_user(
        "bl_ext.user_default.rstrace", path="numba_cache")
    runtime = sys.modules["bl_ext.user_default.rstrace"].runtime
    result["shipped"] = runtime.shipped_status()
    result["numba_cpu"] = numba.config.CPU_NAME
    from rstrace_engine import kernel_cache
    since = kernel_cache.mark()

    sc = bpy.context.scene  # (reading factory settings would disable the extension)
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob)
    sc.render.engine = "RSTRACE"
    sc.render.resolution_x, sc.render.resolution_y, sc.render.resolution_percentage = 24, 18, 100
    sc.rstrace.samples, sc.rstrace.max_ray_depth = 1, 1
    me = bpy.data.meshes.new("Quad")
    me.from_pydata([(-3, -3, 0), (3, -3, 0), (3, 3, 0), (-3, 3, 0)], [], [(0, 1, 2, 3)])
    ob = bpy.data.objects.new("Floor", me)
    sc.collection.objects.link(ob)
    light = bpy.data.lights.new("Lamp", "POINT")
    light.energy = 500.0
    lo = bpy.data.objects.new("Lamp", light)
    lo.location = (0, 0, 3)
    sc.collection.objects.link(lo)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.location = (0, 0, 8)
    sc.collection.objects.link(cam)
    sc.camera = cam
    ims = sc.render.image_settings
    ims.media_type = "MULTI_LAYER_IMAGE"
    ims.color_depth, ims.exr_codec = "32", "NONE"
    sc.render.filepath = os.path.join(out_dir, "installed.exr")
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    result["first_render_s"] = time.perf_counter() - t0
    result["first_render_compiled"] = kernel_cache.counts(since=since)["compiled_kernels"]
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    result["second_render_s"] = time.perf_counter() - t0
    result["image"] = sc.render.filepath
    cache = result["cache_dir"] or ""
    result["cached_kernels"] = sum(f.endswith(".nbi") for _, _, fs in os.walk(cache) for f in fs)

    repos = [r.module for r in bpy.context.preferences.extensions.repos]
    bpy.ops.extensions.package_uninstall(repo_index=repos.index("user_default"),
                                         pkg_id="rstrace")
    result["enabled_after_uninstall"] = (
        "bl_ext.user_default.rstrace" in bpy.context.preferences.addons)
    result["files_after_uninstall"] = os.path.exists(os.path.join(
        bpy.utils.user_resource("EXTENSIONS"), "user_default", "rstrace"))
    print("RESULT " + json.dumps(result))
''')


def _zip(tmp_path: Path) -> Path:
    """The linux-x64 zip of this checkout, its kernels compiled for the generic CPU into
    ``build/kernel-cache`` (the build's own, kept between builds: only what changed
    compiles again; a fresh checkout compiles every kernel here, minutes on 2 cores)."""
    if platform.system() != "Linux" or platform.machine() not in ("x86_64", "AMD64"):
        pytest.skip("the install test builds and installs the linux-x64 zip")
    out = tmp_path / "dist"
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "build_extension.py"),
                           "--platforms", "linux-x64", "--out", str(out),
                           "--stage", str(tmp_path / "stage")],
                          capture_output=True, text=True, timeout=3600)
    built = sorted(out.glob("rstrace-*-linux_x64.zip"))
    # always the zip of this checkout: a stale dist/ zip would test old add-on code
    assert proc.returncode == 0 and built, ("building the extension failed:\n"
                                            + proc.stdout[-2000:] + proc.stderr[-2000:])
    return built[-1]


def test_extension_installs_renders_and_uninstalls(tmp_path):
    zip_path = _zip(tmp_path)
    user = tmp_path / "blender_user"
    user.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CACHE_DIR")}
    env["BLENDER_USER_RESOURCES"] = str(user)
    script = tmp_path / "install_and_render.py"
    script.write_text(SCRIPT)
    proc = subprocess.run([sys.executable, str(script), str(zip_path), str(tmp_path), str(ROOT)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, proc.stdout[-3000:] + proc.stderr[-3000:]
    r = json.loads(lines[-1][len("RESULT "):])
    print("install test:", {k: v for k, v in r.items() if k.endswith("_s")})
    assert r["enabled"]
    assert r["warm_cache_operator"]
    assert r["engine_file"].startswith(str(user)), "rstrace_engine must come from the wheel"
    assert r["cache_dir"] == r["expected_cache_dir"] and r["cached_kernels"] > 0
    # the compiled kernels shipped in the zip were used: the first render compiled nothing
    assert r["shipped"] == "" and r["numba_cpu"] == "generic", r["shipped"]
    assert r["first_render_compiled"] == {}, r["first_render_compiled"]
    import zipfile

    with zipfile.ZipFile(zip_path) as z:
        manifest = json.loads(z.read("kernel_cache/rstrace-kernels.json"))
        assert manifest["shipped"] and manifest["cpu"] == "generic"
        assert manifest["platform"] == "linux-x64" and manifest["signatures"] > 100
    from .exr import read_exr, read_pass

    combined = read_pass(read_exr(r["image"]), "Combined", components="RGB")
    assert combined.shape == (18, 24, 3) and combined.max() > 0.05
    assert not r["enabled_after_uninstall"] and not r["files_after_uninstall"]
