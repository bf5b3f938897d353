"""The small test scene of ``first_render.py`` and ``second_process.py``, as source text.

Both scripts run their measurement in a fresh process (``bpy`` as a module stands in for
Blender) from a script they write out, which cannot import this repository (the first-render
script measures the installed extension alone). :data:`SOURCE` defines
``build_small_scene(bpy, width, height)`` for those scripts to splice in: the current scene
emptied, set to RSTrace at ``width`` x ``height``, a floor, three spheres (red, a mirror,
blue; Principled, roughness 0.5 but the mirror's 0), a 1000 W point light and a camera.
"""

from __future__ import annotations

import textwrap

SOURCE = textwrap.dedent('''
    def build_small_scene(bpy, width, height):
        sc = bpy.context.scene
        for ob in list(bpy.data.objects):
            bpy.data.objects.remove(ob)
        sc.render.engine = "RSTRACE"
        sc.render.resolution_x, sc.render.resolution_y = width, height
        sc.render.resolution_percentage = 100

        def material(name, color, metallic=0.0, roughness=0.5):
            m = bpy.data.materials.new(name)
            bsdf = m.node_tree.nodes["Principled BSDF"]
            bsdf.inputs["Base Color"].default_value = (*color, 1.0)
            bsdf.inputs["Metallic"].default_value = metallic
            bsdf.inputs["Roughness"].default_value = roughness
            return m

        bpy.ops.mesh.primitive_plane_add(size=12.0)
        bpy.context.object.data.materials.append(material("Floor", (0.6, 0.6, 0.6)))
        for name, x, mat in (("Red", -1.6, material("RedM", (0.8, 0.1, 0.1))),
                             ("Mirror", 0.0, material("MirrorM", (0.9, 0.9, 0.9), 1.0, 0.0)),
                             ("Blue", 1.6, material("BlueM", (0.1, 0.2, 0.8)))):
            bpy.ops.mesh.primitive_uv_sphere_add(radius=0.7, location=(x, 0.0, 0.7),
                                                 segments=32, ring_count=16)
            bpy.context.object.name = name
            bpy.context.object.data.materials.append(mat)
        light = bpy.data.lights.new("Lamp", "POINT")
        light.energy = 1000.0
        lo = bpy.data.objects.new("Lamp", light)
        lo.location = (2.0, -3.0, 5.0)
        sc.collection.objects.link(lo)
        cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
        cam.location, cam.rotation_euler = (0.0, -7.0, 3.0), (1.2, 0.0, 0.0)
        sc.collection.objects.link(cam)
        sc.camera = cam
        return sc
''')
