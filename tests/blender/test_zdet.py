import numpy as np
from tests.blender import builders as b

def test_twice(tmp_path):
    sc = b.three_spheres_scene(96, 72)
    sc.rstrace.samples = 1
    sc.rstrace.max_ray_depth = 2
    a = b.render_exr(tmp_path / "a.exr")["Combined"][..., :3]
    c = b.render_exr(tmp_path / "c.exr")["Combined"][..., :3]
    import addon
    addon.session.forget_all()
    d = b.render_exr(tmp_path / "d.exr")["Combined"][..., :3]
    print("a-c", np.abs(a-c).max(), (np.abs(a-c)>1e-6).mean())
    print("a-d", np.abs(a-d).max(), (np.abs(a-d)>1e-6).mean())
    print("c-d", np.abs(c-d).max(), (np.abs(c-d)>1e-6).mean())
