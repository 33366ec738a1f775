"""Import a forest USD scene into real Blender (the ``bpy`` package from PyPI) and check what
Blender shows. Run with the Blender venv's Python, not the project's:

    .venv-blender/bin/python tests/blender_import_check.py SCENE.usdc \
        --instances N --trees T --frames F [--expect EXPECT.npz] [--json-out REPORT.json]

Checks (each failure is listed under "failures" and makes the exit status 1):

* every PointInstancer instance is drawn: Blender 4.2+ imports a PointInstancer as a point cloud
  with a Geometry Nodes "Instance on Points" modifier; the instances are counted in the
  evaluated depsgraph (``depsgraph.object_instances``), and no prototype is drawn on its own;
* one armature per tree, each with an action keyed on every frame ``0 .. F-1``, whose bones
  move between the first and the last frame (the wind plays);
* one skinned mesh per tree whose evaluated vertices move between those frames, with every
  vertex fully weighted to bones of its armature (Blender names vertex groups by the joint's
  last path element, so joints sharing a leaf name lose their weights);
* with ``--expect`` (written by tests/test_blender.py from the same file with pxr): the instance
  transforms and the skinned points on every frame match what USD computes (UsdSkel), and
  every leaf vertex lies within its cloud's branch radius of USD's skinning of it;
* with ``--tile-images N``: one UDIM image with N tiles, every tile's file found, pixels read.

The JSON report is printed as the last line of stdout (and written to ``--json-out``).
The script needs only bpy and numpy; it runs on Blender 4.2 through 5.x.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

try:
    import bpy
except ImportError:  # pragma: no cover - depends on the interpreter
    sys.exit(
        "blender_import_check.py needs Blender's bpy module: run it with "
        ".venv-blender/bin/python (create it with: bash tests/setup_blender_venv.sh)"
    )

IMPORT_OPTIONS: dict[str, Any] = {
    "import_meshes": True,
    "import_points": True,
    "import_skeletons": True,
    "import_blendshapes": True,
    "import_materials": True,
    "import_usd_preview": True,
    "read_mesh_uvs": True,
    "read_mesh_attributes": True,
    "import_render": True,  # the skinned "Bark" mesh (purpose render)
    "import_proxy": False,  # the decimated "Proxy" would otherwise be drawn over it
    "import_guide": False,
    "import_visible_only": True,
    "support_scene_instancing": True,
    "set_frame_range": True,
    "scale": 1.0,
}
SUFFIX = re.compile(r"\.\d{3,}$")  # Blender's ".001" added to clashing names
MOVE_EPS = 1e-7  # metres (or matrix units) below which nothing counts as moving


def base_name(name: str) -> str:
    return SUFFIX.sub("", name)


def usd_import(path: Path) -> tuple[dict[str, Any], list[str], float]:
    """Import into an empty scene with the options this Blender has; returns the options used,
    the ones it lacks and the seconds taken."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    have = {p.identifier for p in bpy.ops.wm.usd_import.get_rna_type().properties}
    used = {k: v for k, v in IMPORT_OPTIONS.items() if k in have}
    missing = sorted(set(IMPORT_OPTIONS) - have)
    t0 = time.perf_counter()
    result = bpy.ops.wm.usd_import(filepath=str(path), **used)
    took = time.perf_counter() - t0
    if "FINISHED" not in result:
        raise SystemExit(f"FAILED: bpy.ops.wm.usd_import returned {result} for {path}")
    return used, missing, took


def instancer_objects() -> list[bpy.types.Object]:
    """Objects whose Geometry Nodes instance on points: Blender's PointInstancers."""
    out = []
    for ob in bpy.context.scene.objects:
        for md in ob.modifiers:
            if (
                md.type == "NODES"
                and md.node_group
                and any(n.bl_idname == "GeometryNodeInstanceOnPoints" for n in md.node_group.nodes)
            ):
                out.append(ob)
                break
    return out


def drawn_instances(
    instancers: list[bpy.types.Object],
) -> tuple[dict[str, list[tuple[str, np.ndarray]]], list[str]]:
    """Per instancer object: (prototype object name, 4x4 world matrix) of every instance in the
    evaluated depsgraph; and the objects drawn on their own that some instancer instances."""
    dg = bpy.context.evaluated_depsgraph_get()
    names = {ob.name for ob in instancers}
    per: dict[str, list[tuple[str, np.ndarray]]] = {n: [] for n in names}
    standalone: set[str] = set()
    for inst in dg.object_instances:
        if inst.is_instance:
            parent = inst.parent.original.name if inst.parent else ""
            if parent in per:
                per[parent].append((inst.object.original.name, np.array(inst.matrix_world)))
        else:
            standalone.add(inst.object.original.name)
    protos = {p for lst in per.values() for p, _ in lst}
    return per, sorted(protos & standalone)


def action_fcurves(ob: bpy.types.Object) -> list[Any]:
    """F-curves of the object's action: legacy ``action.fcurves`` (4.x) or the channelbag of the
    object's slot (layered actions, required from 5.0)."""
    ad = ob.animation_data
    if ad is None or ad.action is None:
        return []
    act = ad.action
    slot = getattr(ad, "action_slot", None)
    if getattr(act, "layers", None) and slot is not None:
        curves: list[Any] = []
        for layer in act.layers:
            for strip in layer.strips:
                bag = strip.channelbag(slot)
                if bag is not None:
                    curves.extend(bag.fcurves)
        if curves:
            return curves
    return list(getattr(act, "fcurves", []))


def ancestor_names(ob: bpy.types.Object) -> list[str]:
    out = []
    p = ob.parent
    while p is not None:
        out.append(base_name(p.name))
        p = p.parent
    return out


def tree_name(ob: bpy.types.Object) -> str | None:
    """The Tree_NNNNN (SkelRoot) above an object, by its imported name."""
    for n in ancestor_names(ob):
        if n.startswith("Tree_"):
            return n
    return None


def pose_matrices(arm: bpy.types.Object) -> np.ndarray:
    return np.array([np.array(pb.matrix) for pb in arm.pose.bones])


def world_points(ob: bpy.types.Object) -> np.ndarray:
    """Evaluated (deformed) vertex positions of a mesh object in world space."""
    dg = bpy.context.evaluated_depsgraph_get()
    ev = ob.evaluated_get(dg)
    me = ev.to_mesh()
    try:
        co = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", co)
        mw = np.array(ev.matrix_world)
    finally:
        ev.to_mesh_clear()
    co64 = co.reshape(-1, 3).astype(np.float64)
    return co64 @ mw[:3, :3].T + mw[:3, 3]


def weight_report(mesh_ob: bpy.types.Object, arm: bpy.types.Object | None) -> dict[str, Any]:
    """Vertex groups that name no bone, and vertices whose weights on bone groups do not sum
    to one (their skinning is lost in Blender)."""
    bones = {b.name for b in arm.data.bones} if arm else set()
    groups = {g.index: g.name for g in mesh_ob.vertex_groups}
    deform = {i for i, n in groups.items() if n in bones}
    under = 0
    worst = 1.0
    for v in mesh_ob.data.vertices:
        total = sum(g.weight for g in v.groups if g.group in deform)
        worst = min(worst, total)
        if total < 0.999:
            under += 1
    return {
        "vertex_groups": len(groups),
        "groups_without_bone": sorted(set(groups.values()) - bones)[:10],
        "underweighted_vertices": under,
        "min_vertex_weight": round(worst, 6),
    }


def axis_conversion(up_axis: str) -> np.ndarray:
    """USD world -> Blender world (Blender is Z-up; a Y-up stage is turned +90 deg about X)."""
    m = np.eye(4)
    if up_axis.upper() == "Y":
        m[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    return m


def instance_error(
    per: dict[str, list[tuple[str, np.ndarray]]],
    exp_xf: np.ndarray,
    exp_proto: np.ndarray,
    conv: np.ndarray,
) -> float:
    """Largest distance between a drawn instance and its nearest expected instance of the same
    prototype, both ways (order-free: Blender's instance order is not USD's)."""
    got: dict[str, list[np.ndarray]] = {}
    for lst in per.values():
        for proto, m in lst:
            got.setdefault(base_name(proto), []).append(m)
    want: dict[str, list[np.ndarray]] = {}
    for m, proto in zip(conv @ exp_xf, exp_proto, strict=True):
        want.setdefault(str(proto), []).append(m)
    if set(got) != set(want) or any(len(got[k]) != len(want[k]) for k in want):
        return math.inf

    def directed(a: np.ndarray, b: np.ndarray) -> float:
        worst = 0.0
        for i in range(0, len(a), 512):
            d = np.abs(a[i : i + 512, None, :3, :] - b[None, :, :3, :]).max(axis=(2, 3))
            worst = max(worst, float(d.min(axis=1).max()))
        return worst

    err = 0.0
    for k in want:
        a, b = np.array(got[k]), np.array(want[k])
        err = max(err, directed(a, b), directed(b, a))
    return err


def leaves_error(
    ob: bpy.types.Object | None,
    want: np.ndarray,
    radius: np.ndarray,
    conv: np.ndarray,
    info: dict[str, Any],
) -> str | None:
    """Blender's leaf clouds against USD's skinning of them at every expected frame: each
    vertex must lie within its cloud's branch radius (metres, ``radius`` per vertex) of
    where UsdSkel puts it, so every cloud stays on its branch. ``want`` is (frames, v, 3)."""
    if ob is None:
        return "no skinned Leaves mesh"
    if len(ob.data.vertices) != want.shape[1]:
        return f"{ob.name} has {len(ob.data.vertices)} vertices, USD {want.shape[1]}"
    worst = 0.0
    for f in range(want.shape[0]):
        bpy.context.scene.frame_set(f)
        e = want[f] @ conv[:3, :3].T + conv[:3, 3]
        d = np.linalg.norm(world_points(ob) - e, axis=1)
        worst = max(worst, float((d / radius).max()))
    info["leaves_error_of_branch_radius"] = float(f"{worst:.3g}")
    if not worst <= 1.0:
        return f"{ob.name}: a leaf vertex is {worst:.3g} branch radii from USD's skinning"
    return None


def tile_images(expected: int) -> tuple[dict[str, Any], list[str]]:
    """The UDIM bark images Blender loaded: every tile's file found and its pixels read."""
    report: dict[str, Any] = {}
    failures: list[str] = []
    tiled = [im for im in bpy.data.images if im.source == "TILED"]
    report["tiled_images"] = [im.name for im in tiled]
    if len(tiled) != 1:
        return report, [f"{len(tiled)} UDIM images imported, expected 1 (the bark)"]
    im = tiled[0]
    numbers = sorted(t.number for t in im.tiles)
    path = bpy.path.abspath(im.filepath, library=im.library)
    missing = [n for n in numbers if not Path(path.replace("<UDIM>", str(n))).is_file()]
    n_pixels = len(im.pixels)  # reading the pixels loads the image buffer
    # each tile's size comes from its decoded file: 0 x 0 where Blender could not read it
    unread = [t.number for t in im.tiles if t.size[0] <= 0 or t.channels <= 0]
    loaded = bool(im.has_data) and n_pixels > 0 and not unread
    report.update(
        udim_path=path,
        udim_tiles=len(numbers),
        udim_first=numbers[:1],
        udim_loaded=loaded,
        udim_missing=missing,
        udim_unread=unread,
    )
    if len(numbers) != expected:
        failures.append(f"{len(numbers)} UDIM tiles imported, expected {expected}")
    if missing:
        failures.append(f"UDIM tiles {missing[:5]} not found at {path}")
    if not loaded:
        failures.append(f"the UDIM image {im.name}: tiles {unread[:5]} not read ({path})")
    return report, failures


def material_colours() -> dict[str, dict[str, Any]]:
    """Per material on a mesh (by its USD name): the Principled BSDF's Base Color as Blender
    renders it, and whether a node feeds it (an image); Blender's default, 0.8 grey, is what
    an input whose USD network it could not convert becomes."""
    out: dict[str, dict[str, Any]] = {}
    for ob in bpy.context.scene.objects:
        if ob.type != "MESH":
            continue
        for slot in ob.material_slots:
            mat = slot.material
            if mat is None or not mat.use_nodes:
                continue
            bsdf = next(
                (n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"), None
            )
            if bsdf is None:
                continue
            sock = bsdf.inputs["Base Color"]
            out[base_name(mat.name)] = {
                "base_color": [round(float(c), 6) for c in sock.default_value[:3]],
                "linked": sock.is_linked,
            }
    return out


def check(args: argparse.Namespace) -> dict[str, Any]:
    failures: list[str] = []
    report: dict[str, Any] = {"blender": bpy.app.version_string, "scene": str(args.scene)}
    used, missing, took = usd_import(args.scene)
    report.update(
        import_seconds=round(took, 3), import_options=used, options_not_in_blender=missing
    )
    scene = bpy.context.scene
    report["scene_frame_range"] = [scene.frame_start, scene.frame_end]
    report["scene_fps"] = round(scene.render.fps / scene.render.fps_base, 6)
    if args.fps is not None and not math.isclose(report["scene_fps"], args.fps, rel_tol=1e-4):
        # not a failure: Blender (4.2 to 5.0) never takes the frame rate from a USD stage
        report["fps_note"] = (
            f"the scene is {args.fps:g} fps (timeCodesPerSecond) but Blender "
            f"keeps {report['scene_fps']:g}: set Output > Frame Rate by hand"
        )

    # ---- PointInstancer ----------------------------------------------------------------------
    instancers = instancer_objects()
    per, standalone = drawn_instances(instancers)
    n_inst = sum(len(v) for v in per.values())
    report["point_instancers"] = {
        ob.name: {
            "points": len(ob.data.attributes["position"].data)
            if ob.type == "POINTCLOUD" and "position" in ob.data.attributes
            else None,
            "instances": len(per[ob.name]),
            "by_prototype": dict(
                sorted(
                    {
                        base_name(p): sum(1 for q, _ in per[ob.name] if q == p)
                        for p, _ in per[ob.name]
                    }.items()
                )
            ),
        }
        for ob in instancers
    }
    report["instances"] = n_inst
    report["prototypes_drawn_standalone"] = standalone
    if not instancers and args.instances != 0:
        failures.append("no PointInstancer (Geometry Nodes instance-on-points object) imported")
    if args.instances is not None and n_inst != args.instances:
        failures.append(f"Blender draws {n_inst} instances, expected {args.instances}")
    if standalone:
        failures.append(
            f"prototypes drawn on their own (at their own place, not instanced): {standalone}"
        )

    # ---- armatures and skinned meshes --------------------------------------------------------
    arms = [ob for ob in scene.objects if ob.type == "ARMATURE"]
    report["armatures"] = len(arms)
    if args.trees is not None and len(arms) != args.trees:
        failures.append(f"{len(arms)} armatures, expected one per tree ({args.trees})")
    skinned = [
        ob
        for ob in scene.objects
        if ob.type == "MESH"
        and any(m.type == "ARMATURE" and m.object is not None for m in ob.modifiers)
    ]
    report["skinned_meshes"] = len(skinned)
    want_skinned = None if args.trees is None else args.trees * args.meshes_per_tree
    if want_skinned is not None and len(skinned) != want_skinned:
        failures.append(
            f"{len(skinned)} skinned meshes, expected {args.meshes_per_tree} per tree "
            f"({args.trees} trees)"
        )
    frames = args.frames
    animated = frames is not None and frames > 1
    last = (frames - 1) if animated else 0
    if animated and report["scene_frame_range"] != [0, last]:
        failures.append(f"scene frame range {report['scene_frame_range']}, expected [0, {last}]")

    trees: dict[str, dict[str, Any]] = {}
    for arm in sorted(arms, key=lambda o: o.name):
        t = tree_name(arm) or arm.name
        curves = action_fcurves(arm)
        keys = sorted({round(kp.co[0], 6) for fc in curves for kp in fc.keyframe_points})
        ad = arm.animation_data
        renamed = sum(1 for b in arm.data.bones if SUFFIX.search(b.name))
        trees[t] = {
            "armature": arm.name,
            "bones": len(arm.data.bones),
            "bones_renamed_by_blender": renamed,
            "action": ad.action.name if ad and ad.action else None,
            "fcurves": len(curves),
            "keyframes": len(keys),
            "key_range": [keys[0], keys[-1]] if keys else None,
        }
        if animated:
            missing_keys = sorted(set(range(frames)) - {int(k) for k in keys if k == int(k)})
            if not curves:
                failures.append(f"{t}: armature {arm.name} has no animation")
            elif missing_keys:
                failures.append(
                    f"{t}: armature {arm.name} has no keys on frames {missing_keys[:10]}"
                )
    for ob in sorted(skinned, key=lambda o: o.name):
        t = tree_name(ob) or ob.name
        arm = next(m.object for m in ob.modifiers if m.type == "ARMATURE" and m.object)
        info = trees.setdefault(t, {})
        if base_name(ob.name) != "Bark":  # the leaves: their weights only
            info[f"{base_name(ob.name)}_weights"] = weight_report(ob, arm)
            if info[f"{base_name(ob.name)}_weights"]["underweighted_vertices"]:
                failures.append(f"{t}: {ob.name} lost skin weight in Blender")
            continue
        info.update(mesh=ob.name, mesh_armature=arm.name, vertices=len(ob.data.vertices))
        info.update(weight_report(ob, arm))
        if info["groups_without_bone"]:
            failures.append(f"{t}: vertex groups {info['groups_without_bone']} name no bone")
        if info["underweighted_vertices"]:
            failures.append(
                f"{t}: {info['underweighted_vertices']} of {info['vertices']} vertices of "
                f"{ob.name} lost skin weight in Blender (lowest total {info['min_vertex_weight']}"
                f"); {info.get('bones_renamed_by_blender', 0)} bones were renamed because joint "
                f"leaf names repeat, and Blender names vertex groups by the leaf name"
            )

    # ---- does the wind play? -----------------------------------------------------------------
    if animated:
        scene.frame_set(0)
        pose0 = {a.name: pose_matrices(a) for a in arms}
        pts0 = {o.name: world_points(o) for o in skinned}
        scene.frame_set(last)
        for arm in arms:
            t = tree_name(arm) or arm.name
            moved = (
                float(np.abs(pose_matrices(arm) - pose0[arm.name]).max())
                if len(arm.pose.bones)
                else 0.0
            )
            trees[t]["bone_motion"] = moved
            if moved <= MOVE_EPS:
                failures.append(f"{t}: no bone of {arm.name} moves between frames 0 and {last}")
        for ob in skinned:
            t = tree_name(ob) or ob.name
            moved = float(np.linalg.norm(world_points(ob) - pts0[ob.name], axis=1).max())
            trees[t]["vertex_motion"] = moved
            if moved <= MOVE_EPS:
                failures.append(
                    f"{t}: the skinned mesh {ob.name} does not move between frames 0 and {last}"
                )

    # ---- against what USD itself computes ----------------------------------------------------
    if args.expect is not None:
        exp = np.load(args.expect, allow_pickle=False)
        conv = axis_conversion(str(exp["up_axis"]))
        err = instance_error(per, exp["instance_xforms"], exp["instance_protos"], conv)
        report["instance_transform_error"] = err
        if not err <= args.tol:
            failures.append(
                f"instance transforms differ from USD's by {err:.3g} (tolerance "
                f"{args.tol:g}; inf: the prototypes drawn do not match)"
            )
        by_tree = {tree_name(o) or o.name: o for o in skinned if base_name(o.name) == "Bark"}
        leaves_by_tree = {
            tree_name(o) or o.name: o for o in skinned if base_name(o.name) == "Leaves"
        }
        for k, t in enumerate(exp["tree_names"]):
            t = str(t)
            if f"leaves_points_{k}" in exp.files:
                leaf_failure = leaves_error(
                    leaves_by_tree.get(t),
                    exp[f"leaves_points_{k}"],
                    exp[f"leaves_radius_{k}"],
                    conv,
                    trees.setdefault(t, {}),
                )
                if leaf_failure:
                    failures.append(f"{t}: {leaf_failure}")
        for k, t in enumerate(exp["tree_names"]):
            t = str(t)
            want = exp[f"skinned_points_{k}"]  # (frames, v, 3) USD world space
            ob = by_tree.get(t)
            info = trees.setdefault(t, {})
            if ob is None:
                failures.append(f"{t}: no skinned mesh to compare with USD")
                continue
            if len(ob.data.vertices) != want.shape[1]:
                failures.append(
                    f"{t}: {ob.name} has {len(ob.data.vertices)} vertices, USD {want.shape[1]}"
                )
                continue
            diag = float(np.linalg.norm(np.ptp(want[0], axis=0)))
            worst, worst_frame = 0.0, 0
            for f in range(want.shape[0]):
                scene.frame_set(f)
                e = want[f] @ conv[:3, :3].T + conv[:3, 3]
                d = float(np.linalg.norm(world_points(ob) - e, axis=1).max())
                if d > worst:
                    worst, worst_frame = d, f
            tol = args.tol * max(diag, 1.0)
            info.update(
                skin_error=worst,
                skin_error_frame=worst_frame,
                skin_error_of_size=float(f"{worst / diag:.3g}") if diag else None,
                skin_tolerance=tol,
            )
            if not worst <= tol:
                failures.append(
                    f"{t}: Blender's skinned {ob.name} is up to {worst:.3g} m "
                    f"({100 * worst / diag:.1f}% of the tree's size) away from "
                    f"USD's skinning (frame {worst_frame}; tolerance {tol:.3g})"
                )
    if args.tile_images is not None:
        images, image_failures = tile_images(args.tile_images)
        report.update(images)
        failures += image_failures
    report["materials"] = material_colours()
    report["trees"] = trees
    report["failures"] = failures
    report["ok"] = not failures
    return report


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("--instances", type=int, help="PointInstancer instances expected")
    ap.add_argument("--trees", type=int, help="trees expected (armatures, skinned meshes)")
    ap.add_argument("--frames", type=int, help="frames of wind (0 or 1: a still scene)")
    ap.add_argument(
        "--meshes-per-tree", type=int, default=2, help="skinned meshes per tree (bark, leaves)"
    )
    ap.add_argument("--fps", type=float, help="the stage's timeCodesPerSecond (reported only)")
    ap.add_argument("--expect", type=Path, help="npz of USD-computed transforms and points")
    ap.add_argument(
        "--tol",
        type=float,
        default=1e-3,
        help="tolerance: instance matrices (absolute) and skinned points "
        "(fraction of the tree's bounding-box diagonal)",
    )
    ap.add_argument(
        "--tile-images", type=int, help="UDIM bark tiles expected loaded (a --tiles scene)"
    )
    ap.add_argument("--json-out", type=Path)
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    if not args.scene.is_file():
        print(f"FAILED: no such scene {args.scene}", file=sys.stderr)
        return 2
    report = check(args)
    text = json.dumps(report, sort_keys=True, default=float)
    if args.json_out:
        args.json_out.write_text(text + "\n")
    print(text, flush=True)
    for f in report["failures"]:
        print(f"FAILED: {f}", file=sys.stderr)
    return 0 if report["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
