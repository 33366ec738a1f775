"""Each tree baked for DCC tools: SkelRoot + Skeleton + SkelAnimation (pose and wind) + one
skinned quad Mesh with UDIM st, and a decimated proxy Mesh (``purpose = "proxy"``).

PointInstancer prototypes cannot be skinned per instance in USD, hence this second form. The
skeleton lives in the tree's model space (the SkelRoot carries the tree transform), so the
tree's root joint is the identity and every other local transform is the generator's own.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import fast_simplification
import numpy as np
from numpy.typing import NDArray
from pxr import Gf, Kind, Usd, UsdGeom, UsdShade, UsdSkel, Vt

from forest.geometry.pieces import MAX_INFLUENCES
from forest.geometry.transforms import (
    F64,
    compose_similarity,
    decompose_similarity,
    invert_similarity,
    rotation_y,
    similarity_scale,
    transform_points,
    transform_vectors,
)
from forest.geometry.weld import close_pairs, weld_labels
from forest.growth.foliage import FoliageAnchors, anchor_positions
from forest.growth.generate import Forest
from forest.growth.joint_budget import DCC_JOINTS, merge_influences
from forest.growth.joints import DccJoints, bind_transforms, dcc_joints, tree_slices
from forest.lod.select import BarkMesh, LeavesMesh
from forest.usd.contract import (
    ASSET_SEED,
    ASSET_TREE,
    BARK_MESH,
    LEAVES_MESH,
    LEAVES_PROXY_MESH,
    PROXY_MESH,
    SKELETON,
    TREES,
    WIND_ANIMATION,
    tree_name,
)
from forest.usd.materials import leaf_material, tile_udim_st
from forest.usd.prims import row_major, time_code
from forest.usd.skin_prims import bind_skin, define_mesh, indexed_st, write_leaves

if TYPE_CHECKING:
    from forest.usd.lod import LodOptions

PROXY_KEEP = 0.2  # fraction of triangles the proxy keeps
Progress = Callable[[str, int, int], None]


def joint_paths(forest: Forest, inst: slice, joints: slice, budget: int | None = None) -> list[str]:
    """UsdSkel joint paths (parent-first) of one tree's joints (:func:`dcc_joints`)."""
    dcc = dcc_joints(forest, budget)
    parent = dcc.parent[joints] - joints.start
    bone = dcc.bone[joints]
    joint = forest.bones.joint[bone]
    local_inst = forest.bones.instance[bone] - inst.start
    out: list[str] = []
    for i in range(joints.stop - joints.start):
        # every joint's own name is unique in the skeleton: Blender names bones and vertex
        # groups by it, and drops the weights of a repeated one
        leaf = f"p{local_inst[i]}"
        if joint[i] == 1:
            leaf += "_hub"
        elif joint[i] > 1:
            leaf += f"_tip{joint[i] - 2}"
        out.append(leaf if parent[i] < 0 else f"{out[parent[i]]}/{leaf}")
    return out


WELD_TOL = 1e-6  # metres: rims coincide at rest to rounding, far below any vertex spacing


def tree_mesh(
    forest: Forest,
    inst: slice,
    bones: slice,
    to_tree: F64,
    still: F64,
    weld: bool = False,
    budget: int | None = None,
) -> tuple[F64, F64, NDArray[np.int32], NDArray[np.int32], F64, F64]:
    """One tree's pieces in tree space as the tree stands (skinned with ``still``, the posed,
    windless palette: the skinned forms' bind pose, :attr:`JointFrames.still`): points,
    normals, quads, joint indices (into the tree's joints ``bones``, a range of
    :func:`dcc_joints` ``(forest, budget)``; a vertex names each joint once), joint weights
    and ``(q, 4, 2)``
    faceVarying UDIM st. With ``weld``, rims of joined pieces (which coincide posed and are
    skinned alike) share vertices (the first piece's skin) with averaged normals: no crease
    at a seam."""
    model, model_n, quads, bone, jw, st = [], [], [], [], [], []
    base = 0
    for i in range(inst.start, inst.stop):
        p = forest.pieces[forest.graph.piece[i]]
        model.append(p.positions)
        model_n.append(p.normals)
        quads.append(p.quads + base)
        bone.append(p.joint_indices + forest.bones.offset[i])
        jw.append(p.joint_weights)
        base += len(p.positions)
    # every quad's tile st in one call (a call per piece was a tenth of a .glb's tree)
    per_piece = np.array([len(p.quads) for p in forest.pieces])[forest.graph.piece[inst]]
    row = np.repeat(np.arange(inst.start, inst.stop), per_piece)
    col = np.arange(len(row)) - np.repeat(np.cumsum(per_piece) - per_piece, per_piece)
    st.append(tile_udim_st(forest.tile_indices[row, col]))
    weights, bone_all = np.concatenate(jw), np.concatenate(bone)
    # every vertex's linear blend of its palette entries, into tree space, in one pass
    blend = to_tree @ np.einsum("vk,vkij->vij", weights, still[bone_all])
    lin = blend[:, :3, :3]
    pts = [np.einsum("vij,vj->vi", lin, np.concatenate(model)) + blend[:, :3, 3]]
    n = np.einsum("vji,vj->vi", np.linalg.inv(lin), np.concatenate(model_n))
    nrm = [n / np.linalg.norm(n, axis=1, keepdims=True)]
    jidx_all, weights = merge_influences(
        dcc_joints(forest, budget).of_bone[bone_all] - bones.start, weights
    )
    jidx, jw = [jidx_all], [weights]
    if not weld:
        return (
            np.concatenate(pts),
            np.concatenate(nrm),
            np.concatenate(quads).astype(np.int32),
            np.concatenate(jidx).astype(np.int32),
            np.concatenate(jw),
            np.concatenate(st),
        )
    all_pts = np.concatenate(pts)
    # coincident vertices (within WELD_TOL, any grid would split some pairs) form groups;
    # each group keeps its first vertex, so the order is stable and deterministic
    n_pts = len(all_pts)
    first = weld_labels(n_pts, close_pairs(all_pts, WELD_TOL))
    keep = np.unique(first)
    rank = np.zeros(n_pts, np.int64)
    rank[keep] = np.arange(len(keep))
    remap = rank[first]
    normals = np.zeros((len(keep), 3))
    np.add.at(normals, remap, np.concatenate(nrm))
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    return (
        all_pts[keep],
        normals,
        remap[np.concatenate(quads)].astype(np.int32),
        np.concatenate(jidx)[keep].astype(np.int32),
        np.concatenate(jw)[keep],
        np.concatenate(st),
    )


def leaves_mesh(
    forest: Forest,
    anchors: FoliageAnchors,
    inst: slice,
    bones: slice,
    to_tree: F64,
    still: F64,
    budget: int | None = None,
) -> tuple[F64, F64, NDArray[np.int32], F64, NDArray[np.int32], NDArray[np.float32]] | None:
    """One tree's leaf clouds as one mesh in tree space as the tree stands (each cloud model
    turned by its yaw, scaled by its size, at its centre on ``still``, the posed, windless
    palette): points, normals, quads,
    vertex st, the tree-local joint of each vertex (its cloud's hub bone's joint of
    :func:`dcc_joints` ``(forest, budget)``; rigid, weight 1)
    and per-face colour. None when the tree bears no clouds."""
    sel = np.flatnonzero((anchors.instance >= inst.start) & (anchors.instance < inst.stop))
    if not len(sel):
        return None
    of_bone = dcc_joints(forest, budget).of_bone
    models = anchors.models()
    centre = anchor_positions(still, anchors.bone[sel], anchors.rest[sel])
    model = anchors.model[sel]
    n_points = np.array([len(c.positions) for c in models])[model]
    n_quads = np.array([len(c.quads) for c in models])[model]
    first_point = np.cumsum(n_points) - n_points
    first_quad = np.cumsum(n_quads) - n_quads
    rot_t = rotation_y(anchors.yaw[sel])[:, :3, :3].transpose(0, 2, 1)  # each cloud's rot.T
    world = np.empty((int(n_points.sum()), 3))
    turned = np.empty_like(world)
    quads = np.empty((int(n_quads.sum()), 4), np.int64)
    st = np.empty((len(world), 2), models[0].st.dtype)
    # the clouds of one model at once, in their places in the tree's mesh: a stacked matmul
    # is the same BLAS product per cloud as one cloud's (the same floats), without a numpy
    # round per cloud (an oak has about 1,600)
    for m in np.unique(model):
        c = models[m]
        ks = np.flatnonzero(model == m)
        at = (first_point[ks][:, None] + np.arange(len(c.positions))).ravel()
        scaled = anchors.size[sel[ks]][:, None, None] * c.positions
        world[at] = (centre[ks][:, None, :] + scaled @ rot_t[ks]).reshape(-1, 3)
        turned[at] = (c.normals @ rot_t[ks]).reshape(-1, 3)
        st[at] = np.tile(c.st, (len(ks), 1))
        rows = (first_quad[ks][:, None] + np.arange(len(c.quads))).ravel()
        quads[rows] = (c.quads[None] + first_point[ks][:, None, None]).reshape(-1, 4)
    n = transform_vectors(to_tree, turned)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    joint = np.repeat((of_bone[anchors.bone[sel]] - bones.start).astype(np.int32), n_points)
    return (
        transform_points(to_tree, world),
        n,
        quads.astype(np.int32),
        st,
        joint,
        np.repeat(anchors.color[sel], n_quads, axis=0).astype(np.float32),
    )


def _proxy(
    stage: Usd.Stage,
    path: str,
    pts: F64,
    quads: NDArray[np.int32],
    skel: UsdSkel.Skeleton,
    jidx: NDArray[np.int32],
    jw: F64,
) -> UsdGeom.Mesh:
    """Decimated triangle mesh with vertex normals; each vertex takes the skin of the
    nearest of the full-mesh vertices that the decimation collapsed into it (the nearest
    vertex overall may lie on a neighbouring branch and swing with that one instead)."""
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    pts32 = pts.astype(np.float32)
    *_, collapses = fast_simplification.simplify(
        pts32, tris, 1.0 - PROXY_KEEP, return_collapses=True
    )
    p2, f2, to_proxy = fast_simplification.replay_simplification(pts32, tris, collapses)
    p2 = np.asarray(p2, np.float64)
    f2 = np.asarray(f2, np.int32)
    near = nearest_source(pts, p2, np.asarray(to_proxy, np.intp))
    face_n = np.cross(p2[f2[:, 1]] - p2[f2[:, 0]], p2[f2[:, 2]] - p2[f2[:, 0]])
    normals = np.zeros_like(p2)
    for c in range(3):
        np.add.at(normals, f2[:, c], face_n)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    # a vertex the decimation left in no face gets up, so every normal has unit length
    normals = np.where(length > 1e-12, normals / np.maximum(length, 1e-12), [0.0, 1.0, 0.0])
    mesh = define_mesh(stage, path, p2, normals, f2, UsdGeom.Tokens.proxy)
    bind_skin(mesh.GetPrim(), skel, jidx[near], jw[near], MAX_INFLUENCES)
    return mesh


def nearest_source(pts: F64, p2: F64, to_proxy: NDArray[np.intp]) -> NDArray[np.intp]:
    """Per decimated vertex of ``p2``, the nearest of the full-mesh vertices ``pts`` mapped to
    it by ``to_proxy`` (``-1``: dropped, a vertex in no triangle); a decimated vertex with
    none (which the decimation does not make) takes the nearest mapped vertex's overall."""
    src = np.flatnonzero(to_proxy >= 0)
    dst = to_proxy[src]
    dist = np.einsum("ij,ij->i", pts[src] - p2[dst], pts[src] - p2[dst])
    order = np.lexsort((src, dist, dst))  # by proxy vertex, then distance: the first wins
    first = np.ones(len(order), bool)
    first[1:] = dst[order[1:]] != dst[order[:-1]]
    near = np.full(len(p2), -1, np.intp)
    near[dst[order[first]]] = src[order[first]]
    for j in np.flatnonzero(near < 0):
        near[j] = src[np.argmin(np.einsum("ij,ij->i", pts[src] - p2[j], pts[src] - p2[j]))]
    return near


def write_skinned_trees(
    stage: Usd.Stage,
    forest: Forest,
    material: UsdShade.Material,
    anchors: FoliageAnchors | None = None,
    progress: Progress | None = None,
    leaf_file: str | None = None,
    bark_st: Callable[[F64], F64] | None = None,
    joint_budget: int | None = DCC_JOINTS,
    lod: LodOptions | None = None,
) -> None:
    """``/World/Forest/Trees`` (a group) of one SkelRoot component per tree: Skeleton with
    its wind animation, the welded skinned Bark, its Proxy, and the tree's leaf clouds
    (Leaves, each cloud bound rigidly to its hub's joint; cut to leaves by ``leaf_file``,
    see :func:`forest.usd.materials.leaf_material`). ``bark_st`` maps the bark's UDIM st to
    what the material reads (a .usdz's atlas). Extents are authored per frame on every
    prim whose points or joints move. ``joint_budget``: joints per tree
    (:mod:`forest.growth.joint_budget`; twigs move rigidly with their limb's joint), None
    for one joint per bone. With ``lod``, each tree's levels of detail as the variant set
    ``lod`` (:mod:`forest.usd.lod`; ``lod0``, the default, is the tree as without)."""
    if progress:  # the joint frames first, then a tree of a big species takes seconds
        progress("skinned trees", 0, forest.options.trees)
    trees = UsdGeom.Xform.Define(stage, TREES)
    Usd.ModelAPI(trees).SetKind(Kind.Tokens.group)
    times = forest.frame_times()
    frames_of = joint_frames(forest, joint_budget)
    binds = frames_of.binds
    # a still forest's pose is one sample at time 0: DCC importers read only samples
    frames = [(t, frames_of.unscaled(frames_of.locals(forest, t))) for t in times]
    codes = [Usd.TimeCode(0.0) if t is None else time_code(t, forest.options.fps) for t in times]
    rest_unscaled = frames_of.unscaled(frames_of.rest)
    leaf_materials = None if anchors is None else leaf_material(stage, anchors.color, leaf_file)
    slices = tree_slices(forest, joint_budget)
    for k, (inst, bones) in enumerate(slices):
        path = f"{TREES}/{tree_name(k)}"
        root = UsdSkel.Root.Define(stage, path)
        model = Usd.ModelAPI(root)
        model.SetKind(Kind.Tokens.component)
        model.SetAssetName(tree_name(k))
        model.SetAssetVersion(forest.version)
        root.GetPrim().SetAssetInfoByKey(ASSET_SEED, int(forest.seed))
        root.GetPrim().SetAssetInfoByKey(ASSET_TREE, k)
        m_tree = forest.tree_transforms[k]
        root.AddTransformOp().Set(Gf.Matrix4d(m_tree.T.tolist()))
        to_tree = invert_similarity(m_tree)
        skel = UsdSkel.Skeleton.Define(stage, f"{path}/{SKELETON}")
        joints = joint_paths(forest, inst, bones, joint_budget)
        skel.CreateJointsAttr(joints)
        skel.CreateBindTransformsAttr(row_major(binds[bones]))
        skel.CreateRestTransformsAttr(
            row_major(
                compose_similarity(
                    rest_unscaled[0][bones], rest_unscaled[1][bones], rest_unscaled[2][bones, 0]
                )
            )
        )
        anim = UsdSkel.Animation.Define(stage, f"{path}/{SKELETON}/{WIND_ANIMATION}")
        anim.CreateJointsAttr(joints)
        for tc, (_, (t, q, s)) in zip(codes, frames, strict=True):
            anim.CreateTranslationsAttr().Set(Vt.Vec3fArray.FromNumpy(t[bones]), tc)
            anim.CreateRotationsAttr().Set(Vt.QuatfArray.FromNumpy(q[bones]), tc)
            anim.CreateScalesAttr().Set(Vt.Vec3hArray.FromNumpy(s[bones]), tc)
        UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets(
            [anim.GetPath()]
        )
        pts, nrm, quads, jidx, jw, st = tree_mesh(
            forest, inst, bones, to_tree, frames_of.still, weld=True, budget=joint_budget
        )
        if bark_st is not None:
            st = bark_st(st)  # what the material reads (a .usdz's atlas)
        mesh = define_mesh(stage, f"{path}/{BARK_MESH}", pts, nrm, quads, UsdGeom.Tokens.render)
        indexed_st(mesh.GetPrim(), st, UsdGeom.Tokens.faceVarying)
        bind_skin(mesh.GetPrim(), skel, jidx, jw, MAX_INFLUENCES)
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
        proxy = _proxy(stage, f"{path}/{PROXY_MESH}", pts, quads, skel, jidx, jw)
        mesh.GetPrim().CreateRelationship("proxyPrim").SetTargets([proxy.GetPath()])
        leaves = (
            None
            if anchors is None
            else leaves_mesh(forest, anchors, inst, bones, to_tree, frames_of.still, joint_budget)
        )
        bark = BarkMesh(pts, nrm, quads, jidx, jw, st)
        leaf_mesh = None if leaves is None else LeavesMesh(*leaves)
        levels = None
        if lod is not None:
            from forest.lod.levels import tree_levels

            levels = tree_levels(
                forest, anchors, inst, bones, to_tree, frames_of.still, bark, leaf_mesh,
                joint_budget,
            )  # fmt: skip
        if leaf_mesh is not None and leaf_materials is not None:
            # the farthest level's crown cards stand in for the leaves where a DCC shows
            # proxies: the leaves are most of the tree's vertices
            light = None if levels is None else levels[-1].leaves
            purpose = UsdGeom.Tokens.default_ if light is None else UsdGeom.Tokens.render
            lm = write_leaves(
                stage, f"{path}/{LEAVES_MESH}", skel, leaf_mesh, leaf_materials, purpose
            )
            if light is not None:
                lp = write_leaves(
                    stage, f"{path}/{LEAVES_PROXY_MESH}", skel, light, leaf_materials,
                    UsdGeom.Tokens.proxy,
                )  # fmt: skip
                lm.GetPrim().CreateRelationship("proxyPrim").SetTargets([lp.GetPath()])
        # the skeleton's joints, then the whole tree: one extent per frame, as they move
        for boundable in (skel, root):
            attr = boundable.CreateExtentAttr()
            for i, tc in enumerate(codes):
                extent = UsdGeom.Boundable.ComputeExtentFromPlugins(boundable, tc)
                attr.Set(extent, tc)
                if i == 0:  # and as the default, for tools that read no time
                    attr.Set(extent)
        if lod is not None and levels is not None:  # after the extents: each level takes its own
            from forest.usd.lod import write_tree_lods

            write_tree_lods(
                stage, root.GetPrim(), skel, forest, anchors, levels, bark, leaf_mesh,
                material, leaf_materials, lod,
            )  # fmt: skip
        if progress:
            progress("skinned trees", k + 1, len(slices))


JointTQS = tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float16]]


@dataclass(frozen=True, eq=False)
class JointFrames:
    """A forest's joints (:func:`dcc_joints`) as DCC bones (no scale in their frames), shared
    by every skinned export (USD here, glTF in :mod:`forest.gltf`).

    binds : (k, 4, 4) unscaled joint frames of the bind pose (the tree as it stands: posed,
        no wind) in their tree's space
    rest : (k, 4, 4) the bind pose's local transforms (tree roots at identity), scaled as the
        generator's
    rest_scale, parent_scale : (k,) bound scale of each joint and of its parent, tree space
    tree_root : (t,) int the joint of each tree's root
    still : (b, 4, 4) the posed, windless palette of every bone (prototype space -> world)
        the bind pose and the meshes written in it come from
    """

    joints: DccJoints
    binds: F64
    rest: F64
    rest_scale: F64
    parent_scale: F64
    tree_root: NDArray[np.intp]
    still: F64

    def locals(self, forest: Forest, time: float | None) -> F64:
        """``(k, 4, 4)`` the joints' local transforms at ``time`` (None: the still pose)."""
        return self.joints.locals(forest.local_bones(time))

    def unscaled(self, local: F64) -> JointTQS:
        """Local transforms ``(k, 4, 4)`` -> translations (k, 3) float32, xyzw rotations
        (k, 4) float32 and scales (k, 3) float16 of the unscaled joints."""
        t, q, scale = decompose_similarity(local)
        t *= self.parent_scale[:, None]
        # the pose's own scale (the rounded radius scale) is all that is left: exact in half
        s = np.repeat((scale / self.rest_scale)[:, None], 3, axis=1).astype(np.float16)
        root = self.tree_root
        t[root], q[root], s[root] = 0.0, (0.0, 0.0, 0.0, 1.0), 1.0
        return t.astype(np.float32), q.astype(np.float32), s


def joint_frames(forest: Forest, budget: int | None = None) -> JointFrames:
    """The forest's joints without scale in their frames, bound as the tree stands.

    The bind pose is the posed tree without wind, so the meshes are written at their true
    size and a still frame's joint transforms are the identity. The generator's own rest
    layout (topological transforms) would not do: along a long axis each step is thinner
    at rest than posed, so a pine's or spruce's top is microns across there, float32 points
    lost centimetres, and the joints' scales grew to thousands up the leader.

    Joint frames are stored without scale (DCC bones cannot hold one): with s_j the bound
    scale of joint j in tree space, each local becomes S(s_parent) @ L @ S(1 / s_j), i.e.
    the translation times s_parent and the scale divided by the bound local scale (1 for
    every frame: wind turns joints, it does not scale them)."""
    b, g = forest.bones, forest.graph
    dcc = dcc_joints(forest, budget)
    still = forest.palette()
    tree_root = dcc.of_bone[b.offset[g.parent < 0]]
    rest = dcc.locals(forest.local_bones(None))
    rest[tree_root] = np.eye(4)
    binds = bind_transforms(forest, still)[dcc.bone]
    bind_scale = similarity_scale(binds)
    binds[:, :3, :3] /= bind_scale[:, None, None]
    parent_scale = np.where(dcc.parent >= 0, bind_scale[np.maximum(dcc.parent, 0)], 1.0)
    parent_scale[tree_root] = 1.0
    return JointFrames(dcc, binds, rest, similarity_scale(rest), parent_scale, tree_root, still)
