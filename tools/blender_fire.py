# Loads a `flamerig run` Blender sequence (OUT/blender/frame_NNNNNN.vdb) into Blender as one volume
# object with the physically right fire material, and optionally renders it.
#
#   blender --background --python tools/blender_fire.py -- OUT/blender [--exposure S]
#           [--render OUT.png] [--frame N] [--samples N]
#   (or from Blender's Scripting tab, with the same arguments in sys.argv after "--")
#
# The material (tools/blender_export.h says what each grid holds):
#   Principled Volume: Color black (soot absorbs, it does not scatter), Density 1 with the `density`
#   grid (the absorption coefficient at 550 nm, 1/m), Emission Strength 1 with Emission Color from
#   the `emission` grid (the radiance our renderer integrates, per metre), Blackbody Intensity 0.
# The film exposure is set to log2(S) stops (S: the fitted camera exposure, in each frame's .vdb
# metadata and in OUT/frames.csv) and the view transform to Standard, so that a render through a
# camera placed like the rig's shows what that camera recorded.
#
# Without this script: Add > Volume > Import OpenVDB, select every frame_NNNNNN.vdb, and give the
# object a Principled Volume with Color black, Blackbody Intensity 1 and Temperature 1 (README).
import argparse
import glob
import math
import os
import sys

import bpy
import mathutils


def parse():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(description="Load a flamerig Blender sequence")
    p.add_argument("folder", help="OUT/blender of a flamerig run")
    p.add_argument("--exposure", type=float, default=1.0,
                   help="the fitted camera exposure (film exposure = log2 of it)")
    p.add_argument("--render", default="", help="render this frame to a PNG file")
    p.add_argument("--frame", type=int, default=1, help="scene frame to render (1 = the first)")
    p.add_argument("--samples", type=int, default=64)
    p.add_argument("--blackbody", action="store_true",
                   help="the Principled Volume's own blackbody from the temperature grid instead "
                        "(what the README's settings give without this script)")
    return p.parse_args(argv)


def blackbody_material():
    # The README's settings: nothing but the Principled Volume and its built-in attributes.
    mat = bpy.data.materials.new("flamerig fire (blackbody)")
    mat.use_nodes = True
    vol = mat.node_tree.nodes["Principled Volume"]
    vol.inputs["Color"].default_value = (0, 0, 0, 1)
    vol.inputs["Blackbody Intensity"].default_value = 1.0
    vol.inputs["Temperature"].default_value = 1.0
    return mat


def fire_material():
    mat = bpy.data.materials.new("flamerig fire")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    vol = nodes.new("ShaderNodeVolumePrincipled")
    vol.inputs["Color"].default_value = (0, 0, 0, 1)
    vol.inputs["Density"].default_value = 1.0
    vol.inputs["Blackbody Intensity"].default_value = 0.0
    vol.inputs["Emission Strength"].default_value = 1.0
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_name = "emission"
    links.new(attr.outputs["Color"], vol.inputs["Emission Color"])
    links.new(vol.outputs["Volume"], out.inputs["Volume"])
    return mat


def main():
    args = parse()
    files = sorted(glob.glob(os.path.join(args.folder, "frame_*.vdb")))
    if not files:
        raise SystemExit(f"{args.folder}: no frame_NNNNNN.vdb files")
    bpy.ops.object.volume_import(
        filepath=files[0], directory=args.folder,
        files=[{"name": os.path.basename(f)} for f in files], align="WORLD",
        location=(0, 0, 0))
    obj = bpy.context.active_object
    obj.name = "flamerig fire"
    obj.data.materials.append(blackbody_material() if args.blackbody else fire_material())
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, len(files)
    scene.render.engine = "CYCLES"
    scene.cycles.samples = args.samples
    scene.cycles.use_denoising = False  # Debian's Blender is built without OpenImageDenoise
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.exposure = math.log2(args.exposure)
    if args.render:
        # A camera looking at the fire from the front (the rig's +z, Blender's -y), framing the
        # volume's bounding box to 60% of the image height, and a black world.
        scene.frame_set(args.frame)
        bpy.context.view_layer.update()
        corners = [obj.matrix_world @ mathutils.Vector(c) for c in obj.bound_box]
        lo = [min(c[i] for c in corners) for i in range(3)]
        hi = [max(c[i] for c in corners) for i in range(3)]
        centre = [(a + b) / 2 for a, b in zip(lo, hi)]
        scene.render.resolution_x, scene.render.resolution_y = 320, 240
        bpy.ops.object.camera_add(rotation=(math.pi / 2, 0, 0))
        camera = bpy.context.active_object
        vertical_fov = 2 * math.atan(math.tan(camera.data.angle / 2) * 240 / 320)
        distance = (hi[2] - lo[2]) / 0.6 / (2 * math.tan(vertical_fov / 2)) + (hi[1] - lo[1]) / 2
        camera.location = (centre[0], lo[1] - distance, centre[2])
        scene.camera = camera
        scene.world = scene.world or bpy.data.worlds.new("World")
        scene.world.use_nodes = True
        scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
        scene.render.filepath = os.path.abspath(args.render)
        bpy.ops.render.render(write_still=True)


main()
