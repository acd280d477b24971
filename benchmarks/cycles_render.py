"""Render a SCENE.json with Blender Cycles (CPU) as a linear-radiance reference (benchmark only).

Run in the separate Blender venv, never in the project's (bpy is an optional benchmark
dependency; this file imports nothing from the repo)::

    .bpyenv/bin/python benchmarks/cycles_render.py SCENE.json --spp 256 --out OUT.exr \
        [--threads 2] [--seed 0]

Writes OUT.exr (float32 RGB, H x W, row 0 = image top, linear radiance [W/(m^2 sr)]) and
prints one JSON line: spp, render_s (the render call), total_s (with scene build),
blender_version, width, height. See benchmarks/README_cycles.md for install and calibration.

Conventions (SCENE.json as raytrace.scenefile reads it, with its defaults; body frame =
mesh frame in metres = Blender world frame)
-----------------------------------------------------------------------------------------
Camera
    OpenCV pinhole: p_cam = R_cam_from_body p_body + t_cam_m, x right, y down, z forward,
    u = fx x/z + cx, v = fy y/z + cy, integer (u, v) at pixel centres. Blender cameras look
    along -z with y up, so the camera-to-world rotation is R^T diag(1, -1, -1) and the camera
    centre is -R^T t. Blender's sensor spans the W pixel *edges* and Cycles samples pixel x
    over raster [x, x + 1), so a centred OpenCV principal point ((W-1)/2, (H-1)/2) needs no
    shift: sensor_fit HORIZONTAL, lens/sensor_width = fx/W, and (shift in units of the
    sensor width) shift_x = ((W-1)/2 - cx)/W, shift_y = (cy - (H-1)/2)/W. Requires fx = fy.
    Measured: small-sphere centroids within 0.006 px of the projection.
    [manual: render/cameras.html]
Meshes
    Read with trimesh as raytrace.meshio reads them (process=False, OBJ split per object x
    material, glTF node transforms baked), scaled by unit_scale_m (default 1); positions
    welded, degenerate and duplicate faces dropped. Shading normals are the renderer's
    (raytrace.scene, crease 30 deg): per face corner, the angle-weighted mean of the normals
    of the faces around the welded vertex that lie within 30 deg of this face's, set as
    Blender custom split normals (stored to ~5e-6) on a mesh whose triangles do not share
    vertices (a shared vertex whose faces mix windings garbled the stored normals). Diffuse BSDF, roughness 0 (= exact
    Lambert, no Oren-Nayar), colour = albedo (1 or 3 numbers); two-sided;
    shadow-terminator offsets 0 (plain shadow rays from the flat triangle).
    [manual: render/shader_nodes/shader/diffuse.html, render/cycles/object_settings/object_data.html]
Sun
    SUN light whose +z points along sun_dir_body, strength = sun_irradiance_W_m2 (1361) *
    shadow_fraction (1) -- Cycles sun strength is irradiance in W/m^2 -- and angle = the
    angular diameter (0.533 deg). Shadow linking: only the target meshes block it; the
    eclipse is shadow_fraction's job, so the Earth never shadows the Sun a second time.
    [manual: render/lights/light_object.html, render/lights/light_linking.html]
Earth (optional)
    An exact sphere (one point of a Cycles point cloud, made by a geometry-nodes Points node:
    no tessellation) of radius radius_m (6378137) at earth_distance_m * earth_dir_body. Its
    surface *emits* albedo (0.3) * E * max(n . s, 0) / pi with E = sun_irradiance_W_m2 (the
    full Sun lights the day side whatever the target's shadow_fraction, as in
    raytrace.environment), n the exact sphere normal: the spec's Lambertian day side and
    dark night side, with no ambient or target light bouncing off it. It is seen by camera
    rays, lights the target through its BSDF rays and hides the sky behind it. float32 is
    enough at 6.8e6 m: measured limb within 1e-3 px, day side within 1e-3 of float64.
    [manual: modeling/geometry_nodes/point/points.html]
Ambient
    World Background shader, white, strength ambient_radiance_W_m2_sr (0): radiance 1 per
    unit strength, in every direction the Earth leaves free -- for every ray but camera
    rays: as in raytrace.shade/pathtrace "the sky lights the target but is not drawn", so
    pixels that see neither target nor Earth are 0 (a Light Path "Is Camera Ray" factor;
    --draw-ambient draws it). [manual: render/lights/world.html,
    render/shader_nodes/input/light_path.html]

Units, measured with benchmarks/cycles_calibration.py: Lambert plate facing the sun,
Cycles / (rho E cos / pi) = 1.00000; plate in the white-furnace world, Cycles / (rho L) =
1.00000. The unit factor is 1 and nothing is rescaled. Film and integrator: box filter 1 px,
no denoiser, no adaptive sampling, no clamping, light threshold 0, no path guiding, 32
bounces of every kind, view transform Standard (float EXR is written scene-linear anyway).
[manual: render/cycles/render_settings/sampling.html, .../light_paths.html, .../film.html,
render/color_management.html]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

DEFAULT_CREASE_DEG = 30.0  # raytrace.model.DEFAULT_CREASE_ANGLE_RAD
MAX_BOUNCES = 32


# ----------------------------------------------------------------------------- scene file
def camera_params(cam: dict):
    K = np.asarray(cam["K"], dtype=np.float64)
    W, H = int(cam["width"]), int(cam["height"])
    R = np.asarray(cam["R_cam_from_body"], dtype=np.float64).reshape(3, 3)
    t = np.asarray(cam["t_cam_m"], dtype=np.float64).reshape(3)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if (K.shape != (3, 3) or K[0, 1] != 0 or K[1, 0] != 0 or list(K[2]) != [0, 0, 1]
            or abs(fx - fy) > 1e-9 * fx or fx <= 0):
        raise ValueError(f"cycles_render needs K = [[f, 0, cx], [0, f, cy], [0, 0, 1]] (fx = fy), got {K.tolist()}")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise ValueError("R_cam_from_body must be a proper rotation matrix")
    return W, H, fx, cx, cy, R, t


def load_parts(path: str, scale: float):
    """(vertices [m], faces) per part, read like raytrace.meshio.load_mesh."""
    import trimesh
    ftype = path.rsplit(".", 1)[-1].lower()
    extra = {"split_objects": True} if ftype == "obj" else {}
    scene = trimesh.load_scene(path, file_type=ftype, process=False, **extra)
    parts = []
    for node in scene.graph.nodes_geometry:
        T, gname = scene.graph[node]
        g = scene.geometry.get(gname)
        if not isinstance(g, trimesh.Trimesh) or len(g.faces) == 0:
            continue
        v = (np.asarray(g.vertices, float) @ np.asarray(T)[:3, :3].T + np.asarray(T)[:3, 3]) * scale
        v, inv = np.unique(v + 0.0, axis=0, return_inverse=True)  # weld identical positions
        f = inv.reshape(-1)[np.asarray(g.faces, np.int64)]
        area = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
        f = f[(area > 0) & (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
        _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
        f = f[np.sort(first)]
        if len(f):
            used, f = np.unique(f, return_inverse=True)
            parts.append((v[used], f.reshape(-1, 3)))
    if not parts:
        raise ValueError(f"{path}: no triangles")
    return parts


def corner_normals(V: np.ndarray, F: np.ndarray, crease_rad: float) -> np.ndarray:
    """Per face corner: angle-weighted mean of the normals of the faces around the vertex
    that lie within the crease angle of this face's normal (raytrace._kernels.corner_normals)."""
    tri = V[F]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    ang = np.empty(F.shape)
    for k in range(3):
        a, b = tri[:, (k + 1) % 3] - tri[:, k], tri[:, (k + 2) % 3] - tri[:, k]
        ang[:, k] = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))
    corner_v = F.ravel()                      # corner c = 3 f + k
    order = np.argsort(corner_v, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(corner_v[order]) != 0])
    counts = np.diff(np.r_[starts, len(order)])
    grp = np.repeat(np.arange(len(starts)), counts)          # group of each sorted position
    n_pairs = counts[grp]
    I = np.repeat(np.arange(len(order)), n_pairs)            # sorted position of this corner
    J = starts[grp[I]] + np.arange(len(I)) - np.repeat(np.cumsum(n_pairs) - n_pairs, n_pairs)
    ci, cj = order[I], order[J]
    keep = np.einsum("ij,ij->i", fn[ci // 3], fn[cj // 3]) >= math.cos(crease_rad)
    ci, cj = ci[keep], cj[keep]
    w = ang.ravel()[cj][:, None] * fn[cj // 3]
    out = np.stack([np.bincount(ci, w[:, a], minlength=F.size) for a in range(3)], axis=1)
    n = np.linalg.norm(out, axis=1, keepdims=True)
    return np.where(n > 0, out / np.where(n > 0, n, 1), np.repeat(fn, 3, axis=0))


# ----------------------------------------------------------------------------- bpy scene
def build(sc: dict, base: str, spp: int, threads: int, seed: int, draw_ambient: bool = False):
    import bpy
    from mathutils import Matrix, Vector

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    cyc = scene.cycles
    cyc.device = "CPU"
    cyc.samples = spp
    cyc.seed, cyc.use_animated_seed = seed, False
    cyc.use_adaptive_sampling = False
    cyc.use_denoising = False
    cyc.sample_clamp_direct = cyc.sample_clamp_indirect = 0.0
    cyc.light_sampling_threshold = 0.0
    cyc.use_guiding = False
    cyc.blur_glossy = 0.0
    cyc.pixel_filter_type, cyc.filter_width = "BOX", 1.0
    cyc.film_exposure = 1.0
    for k in ("max_bounces", "diffuse_bounces", "glossy_bounces", "transmission_bounces",
              "volume_bounces", "transparent_max_bounces"):
        setattr(cyc, k, MAX_BOUNCES)
    scene.view_layers[0].cycles.use_denoising = False
    r = scene.render
    r.threads_mode, r.threads = "FIXED", threads
    r.film_transparent = False
    r.use_compositing = r.use_sequencer = False
    r.dither_intensity = 0.0
    r.use_persistent_data = False
    scene.view_settings.view_transform, scene.view_settings.look = "Standard", "None"
    scene.view_settings.exposure, scene.view_settings.gamma = 0.0, 1.0
    im = r.image_settings
    im.file_format, im.color_mode, im.color_depth, im.exr_codec = "OPEN_EXR", "RGB", "32", "ZIP"

    # camera
    W, H, f, cx, cy, R, t = camera_params(sc["camera"])
    r.resolution_x, r.resolution_y, r.resolution_percentage = W, H, 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    cam = bpy.data.cameras.new("camera")
    cam.type, cam.sensor_fit, cam.sensor_width = "PERSP", "HORIZONTAL", 36.0
    cam.lens = f * cam.sensor_width / W
    cam.shift_x, cam.shift_y = ((W - 1) / 2 - cx) / W, (cy - (H - 1) / 2) / W
    cam.clip_start, cam.clip_end = 1e-6, 1e12
    M = np.eye(4)
    M[:3, :3] = R.T @ np.diag([1.0, -1.0, -1.0])
    M[:3, 3] = -R.T @ t
    cam_ob = bpy.data.objects.new("camera", cam)
    cam_ob.matrix_world = Matrix(M.tolist())
    scene.collection.objects.link(cam_ob)
    scene.camera = cam_ob

    def new_material(name):
        mat = bpy.data.materials.new(name)
        if bpy.app.version < (5, 0, 0):
            mat.use_nodes = True  # always on (and deprecated) from Blender 5.0
        return mat

    def diffuse(name, rgb):
        mat = new_material(name)
        nt = mat.node_tree
        nt.nodes.clear()
        bsdf = nt.nodes.new("ShaderNodeBsdfDiffuse")
        bsdf.inputs["Color"].default_value = (*map(float, rgb), 1.0)
        bsdf.inputs["Roughness"].default_value = 0.0
        out = nt.nodes.new("ShaderNodeOutputMaterial")
        nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
        return mat

    # target meshes
    target = bpy.data.collections.new("target")
    scene.collection.children.link(target)
    if "meshes" not in sc:
        raise ValueError("cycles_render supports 'meshes' scenes only (no built-in 'target')")
    for i, m in enumerate(sc["meshes"]):
        if "albedo" not in m or "material" in m:
            raise ValueError("cycles_render supports albedo meshes only")
        mat = diffuse(f"albedo{i}", np.broadcast_to(np.asarray(m["albedo"], float).ravel(), (3,)))
        crease = math.radians(DEFAULT_CREASE_DEG)
        for j, (V, F) in enumerate(load_parts(os.path.join(base, m["path"]), float(m.get("unit_scale_m", 1.0)))):
            N = corner_normals(V, F, crease).astype(np.float32)
            # each triangle its own three vertices (same positions, so the same watertight
            # hits): Blender stores a custom normal relative to the fan of faces around its
            # vertex, and where that fan mixes windings (a mesh with flipped faces) the stored
            # normal came back wrong -- sunlit panels of icesat2.glb rendered black
            V, F = V[F].reshape(-1, 3), np.arange(F.size).reshape(-1, 3)
            me = bpy.data.meshes.new(f"mesh{i}_{j}")
            me.vertices.add(len(V))
            me.vertices.foreach_set("co", V.astype(np.float32).ravel())
            me.loops.add(F.size)
            me.loops.foreach_set("vertex_index", F.astype(np.int32).ravel())
            me.polygons.add(len(F))
            me.polygons.foreach_set("loop_start", np.arange(0, F.size, 3, dtype=np.int32))
            me.polygons.foreach_set("use_smooth", np.ones(len(F), dtype=bool))
            me.update()
            # custom split normals (stored to ~5e-6); a float "custom_normal" corner attribute
            # reads back right but Cycles 5.0.1 ignores it and shades with smooth vertex normals
            me.normals_split_custom_set(N.reshape(-1, 3))
            me.materials.append(mat)
            ob = bpy.data.objects.new(me.name, me)
            ob.shadow_terminator_geometry_offset = 0.0  # plain shadow rays from the flat triangle
            ob.shadow_terminator_shading_offset = 0.0
            target.objects.link(ob)

    # sun
    s = sc["sun"]
    sun_dir = np.asarray(s["sun_dir_body"], float)
    sun_dir /= np.linalg.norm(sun_dir)
    E_sun = float(s.get("sun_irradiance_W_m2", 1361.0))
    light = bpy.data.lights.new("sun", "SUN")
    light.energy = E_sun * float(s.get("shadow_fraction", 1.0))
    light.angle = math.radians(float(s.get("angular_diameter_deg", 0.533)))
    light.color, light.use_temperature, light.exposure = (1.0, 1.0, 1.0), False, 0.0
    light.use_shadow = True
    sun_ob = bpy.data.objects.new("sun", light)
    sun_ob.rotation_mode = "QUATERNION"
    sun_ob.rotation_quaternion = Vector(sun_dir.tolist()).to_track_quat("Z", "Y")  # emits along -z
    scene.collection.objects.link(sun_ob)

    # ambient world
    world = bpy.data.worlds.new("ambient")
    if bpy.app.version < (5, 0, 0):
        world.use_nodes = True
    scene.world = world
    nt = world.node_tree
    nt.nodes.clear()
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    L = float(sc.get("ambient_radiance_W_m2_sr", 0.0))
    if draw_ambient:
        bg.inputs["Strength"].default_value = L
    else:  # strength L * (1 - is_camera_ray): lights the target, camera rays see black space
        path = nt.nodes.new("ShaderNodeLightPath")
        strength = nt.nodes.new("ShaderNodeMath")
        strength.operation = "MULTIPLY_ADD"  # is_camera * (-L) + L
        strength.inputs[1].default_value, strength.inputs[2].default_value = -L, L
        nt.links.new(path.outputs["Is Camera Ray"], strength.inputs[0])
        nt.links.new(strength.outputs["Value"], bg.inputs["Strength"])
    nt.links.new(bg.outputs["Background"], nt.nodes.new("ShaderNodeOutputWorld").inputs["Surface"])

    # Earth: exact emissive sphere, radiance albedo * E * max(n.s, 0) / pi
    e = sc.get("earth")
    if e:
        if e.get("texture", "uniform") != "uniform":
            raise ValueError("cycles_render supports a uniform-albedo Earth only")
        d = np.asarray(e["earth_dir_body"], float)
        centre = d / np.linalg.norm(d) * float(e["earth_distance_m"])
        mat = new_material("earth")
        mt = mat.node_tree
        mt.nodes.clear()
        geo = mt.nodes.new("ShaderNodeNewGeometry")
        dot = mt.nodes.new("ShaderNodeVectorMath")
        dot.operation = "DOT_PRODUCT"
        dot.inputs[1].default_value = sun_dir.tolist()
        mt.links.new(geo.outputs["True Normal"], dot.inputs[0])
        lam = mt.nodes.new("ShaderNodeMath")
        lam.operation = "MAXIMUM"
        lam.inputs[1].default_value = 0.0
        mt.links.new(dot.outputs["Value"], lam.inputs[0])
        scale = mt.nodes.new("ShaderNodeMath")
        scale.operation = "MULTIPLY"
        scale.inputs[1].default_value = float(e.get("albedo", 0.3)) * E_sun / math.pi
        mt.links.new(lam.outputs["Value"], scale.inputs[0])
        em = mt.nodes.new("ShaderNodeEmission")
        em.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        mt.links.new(scale.outputs["Value"], em.inputs["Strength"])
        mt.links.new(em.outputs["Emission"], mt.nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
        # one point-cloud sphere, made by a geometry-nodes Points node on an empty mesh
        gn = bpy.data.node_groups.new("earth", "GeometryNodeTree")
        gn.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
        pts = gn.nodes.new("GeometryNodePoints")
        pts.inputs["Count"].default_value = 1
        pts.inputs["Position"].default_value = centre.tolist()
        pts.inputs["Radius"].default_value = float(e.get("radius_m", 6378137.0))
        setmat = gn.nodes.new("GeometryNodeSetMaterial")
        setmat.inputs["Material"].default_value = mat
        gn.links.new(pts.outputs["Points"], setmat.inputs["Geometry"])
        gn.links.new(setmat.outputs["Geometry"], gn.nodes.new("NodeGroupOutput").inputs[0])
        earth_ob = bpy.data.objects.new("earth", bpy.data.meshes.new("earth"))
        earth_ob.modifiers.new("earth", "NODES").node_group = gn
        scene.collection.objects.link(earth_ob)
        sun_ob.light_linking.blocker_collection = target  # only the target shadows the sun
    return scene, W, H


def main(argv=None):
    t0 = time.perf_counter()
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--spp", type=int, default=None, help="samples per pixel (default: the scene's 'samples')")
    ap.add_argument("--out", required=True, help="output EXR (float32 RGB linear radiance)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=None, help="default: the scene's 'seed' (0)")
    ap.add_argument("--draw-ambient", action="store_true",
                    help="camera rays that miss everything see the ambient sky (default: black, as raytrace)")
    a = ap.parse_args(argv)
    with open(a.scene) as fh:
        sc = json.load(fh)
    spp = a.spp if a.spp is not None else sc.get("samples")
    if not spp or int(spp) < 1:
        raise SystemExit("cycles_render: give --spp N (the scene's 'samples' is null)")
    seed = a.seed if a.seed is not None else int(sc.get("seed") or 0)

    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)  # Blender's own progress output goes to stderr; stdout gets one JSON line
    try:
        import bpy
        scene, W, H = build(sc, os.path.dirname(os.path.abspath(a.scene)), int(spp), a.threads, seed,
                            a.draw_ambient)
        t1 = time.perf_counter()
        bpy.ops.render.render(write_still=False)
        render_s = time.perf_counter() - t1
        bpy.data.images["Render Result"].save_render(os.path.abspath(a.out), scene=scene)
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
    print(json.dumps({"spp": int(spp), "render_s": round(render_s, 4),
                      "total_s": round(time.perf_counter() - t0, 4),
                      "blender_version": bpy.app.version_string, "width": W, "height": H}))


if __name__ == "__main__":
    try:
        main()
    except (ValueError, KeyError, OSError) as exc:  # scene-file problems: one line, exit 1
        sys.exit(f"cycles_render: {type(exc).__name__}: {exc}")
