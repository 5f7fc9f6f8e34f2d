"""The object to reconstruct: Newell's Utah teapot (tessellated from its 32 bicubic Bezier
patches), the Stanford bunny, the Stanford dragon or any mesh file (OBJ, PLY, STL, OFF, glTF/GLB),
oriented and placed on the table;
ground-truth surface samples."""

from __future__ import annotations

import dataclasses as dc
import math
from pathlib import Path

import numpy as np

from ..config import ObjectConfig, Scenario
from ..errors import MeshError, ScenarioError
from ..resources import model_path
from .primitives import box
from .shapes import SHAPES


@dc.dataclass
class ObjectMesh:
    """A triangle mesh in the world frame (metres); `parts`: each triangle's convex part
    (objects built from primitives), or None (one part: the collision model takes its hull)."""
    vertices: np.ndarray  # (V, 3) float64
    triangles: np.ndarray  # (T, 3) int32
    parts: np.ndarray | None = None  # (T,) int32

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def write_obj(self, path: Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "w") as f:
            f.write("# nbvs_drake object mesh (world frame, metres)\n")
            np.savetxt(f, self.vertices, fmt="v %.6f %.6f %.6f")
            np.savetxt(f, self.vertex_normals(), fmt="vn %.6f %.6f %.6f")
            t = self.triangles + 1
            np.savetxt(f, np.repeat(t, 2, axis=1), fmt="f %d//%d %d//%d %d//%d")
        for old in path.parent.glob(f"{path.stem}_part*.obj"):
            old.unlink()
        if self.parts is not None:
            for k in np.unique(self.parts):
                T = self.triangles[self.parts == k]
                used, T = np.unique(T, return_inverse=True)
                ObjectMesh(self.vertices[used], T.reshape(-1, 3).astype(np.int32)).write_obj(
                    path.parent / f"{path.stem}_part{k:03d}.obj")
        return path

    @staticmethod
    def part_files(path: Path) -> list[Path]:
        """The convex parts `write_obj` wrote beside `path` (empty: the mesh is one part)."""
        path = Path(path)
        return sorted(path.parent.glob(f"{path.stem}_part*.obj"))

    def vertex_normals(self) -> np.ndarray:
        """Area-weighted vertex normals (unit; +z where undefined)."""
        V, T = self.vertices, self.triangles
        fn = np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]])
        n = np.zeros_like(V)
        for k in range(3):
            np.add.at(n, T[:, k], fn)
        norm = np.linalg.norm(n, axis=1)
        n[norm < 1e-15] = (0.0, 0.0, 1.0)
        norm[norm < 1e-15] = 1.0
        return n / norm[:, None]


# --------------------------------------------------------------------------------------
# Utah teapot
# --------------------------------------------------------------------------------------


def load_teapot_patches(path: Path | None = None) -> np.ndarray:
    """Returns the control points of the 32 patches, shape (32, 4, 4, 3), Newell's units."""
    path = Path(path or model_path("utah_teapot_newell.txt"))
    lines = [ln.split() for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    nv = int(lines[0][1])
    verts = np.array([[float(t) for t in ln] for ln in lines[1:1 + nv]])
    npatch = int(lines[1 + nv][1])
    idx = np.array([[int(t) for t in ln] for ln in lines[2 + nv:2 + nv + npatch]]) - 1
    return verts[idx].reshape(npatch, 4, 4, 3)


def _bernstein(t: np.ndarray) -> np.ndarray:
    t = np.asarray(t, float)
    s = 1.0 - t
    return np.stack([s ** 3, 3 * s * s * t, 3 * s * t * t, t ** 3], axis=-1)


def tessellate_teapot(n: int = 12) -> ObjectMesh:
    """Evaluates each Bezier patch on an (n+1)x(n+1) grid and triangulates it. Degenerate
    triangles (the patches that collapse to a point at the lid knob and bottom centre)
    are dropped. Units are Newell's (z up)."""
    patches = load_teapot_patches()
    b = _bernstein(np.linspace(0.0, 1.0, n + 1))  # (n+1, 4)
    verts, tris = [], []
    for P in patches:
        grid = np.einsum("ui,vj,ijk->uvk", b, b, P).reshape(-1, 3)
        base = sum(len(v) for v in verts)
        verts.append(grid)
        ii, jj = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        a = (ii * (n + 1) + jj).ravel()
        t1 = np.stack([a, a + n + 1, a + n + 2], axis=1)
        t2 = np.stack([a, a + n + 2, a + 1], axis=1)
        tris.append(np.concatenate([t1, t2]) + base)
    V = np.concatenate(verts)
    T = np.concatenate(tris)
    # drop degenerate triangles
    e1 = V[T[:, 1]] - V[T[:, 0]]
    e2 = V[T[:, 2]] - V[T[:, 0]]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    T = T[area > 1e-12]
    return ObjectMesh(V, T.astype(np.int32))


# --------------------------------------------------------------------------------------
# Stanford bunny
# --------------------------------------------------------------------------------------

#: bun_zipper (Stanford 3D Scanning Repository) as binary PLY: 35,947 vertices (float32, the
#: source's 6 decimals kept), 69,451 triangles, y up, its units (about 0.156 x 0.154 x 0.121)
BUNNY_FILE = "stanford_bunny.ply"


def load_bunny() -> ObjectMesh:
    """The Stanford bunny in its file's frame and units (y up)."""
    return load_mesh_file(model_path(BUNNY_FILE))


#: the Stanford dragon, low-poly (7,961 vertices, 15,922 triangles, y up, extents about
#: 143 x 97 x 63 in its units), converted from ../shared/objects/stanford_dragon.obj
#: (cgsdev0/teapot models/dragon.obj) to binary PLY, vertices and faces in the source's order
DRAGON_FILE = "stanford_dragon.ply"


def load_dragon() -> ObjectMesh:
    """The Stanford dragon in its file's frame and units (y up, facing +x)."""
    return load_mesh_file(model_path(DRAGON_FILE))


# --------------------------------------------------------------------------------------
# Meshes from files
# --------------------------------------------------------------------------------------


MESH_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".gltf", ".glb")


def load_mesh_file(path: Path) -> ObjectMesh:
    """Reads a triangle mesh with trimesh: OBJ (triangles, quads or n-gons, which it
    triangulates), PLY, STL, OFF, glTF/GLB (every part of the scene, in its node frames,
    joined into one mesh). Vertices and faces are kept as the file has them (no merging)."""
    path = Path(path)
    if not path.is_file():
        raise MeshError(f"object mesh not found: {path}")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise MeshError(f"unsupported mesh format {path.suffix!r} for {path} (use OBJ, PLY, STL, OFF, glTF or GLB)")
    import trimesh
    try:
        m = trimesh.load(str(path), process=False, force="mesh")
        V, T = m.vertices, m.faces
    except Exception as e:  # noqa: BLE001 - trimesh raises many types on a bad file
        V = T = None
        if path.suffix.lower() == ".off":  # trimesh 5.2 fails on OFF n-gons mixed with other faces
            V, T = _read_with_open3d(path)
        if V is None or not len(T):
            raise MeshError(f"cannot read object mesh {path}: {' '.join(str(e).split())[:200] or type(e).__name__}") \
                from None
    V = np.asarray(V, dtype=float).reshape(-1, 3)
    T = np.asarray(T, dtype=np.int32).reshape(-1, 3)
    if len(V) == 0 or len(T) == 0:
        raise MeshError(f"object mesh {path} is unreadable or has no faces")
    if not np.all(np.isfinite(V)):
        raise MeshError(f"object mesh {path} has non-finite vertex coordinates")
    return ObjectMesh(V, T)


def _read_with_open3d(path: Path):
    """(vertices, triangles) by Open3D's reader (it triangulates OFF polygons), or (None, None)."""
    import open3d as o3d
    try:
        m = o3d.io.read_triangle_mesh(str(path))
    except Exception:  # noqa: BLE001
        return None, None
    return np.asarray(m.vertices), np.asarray(m.triangles)


# --------------------------------------------------------------------------------------
# Placement and ground truth
# --------------------------------------------------------------------------------------


def object_size(o: ObjectConfig) -> float:
    """The longest side (m) the object is scaled to; 0: it is scaled by `scale`."""
    return o.resolved_size()


def object_up(o: ObjectConfig) -> str:
    return o.resolved_up()


def up_rotation(up: str) -> np.ndarray:
    """The rotation taking the mesh axis `up` (x, y, z, -x, -y, -z) to world +z: the axes
    are turned cyclically (x -> y -> z -> x) until `up` is z, and a negative axis is then
    turned 180 deg about world x. y: mesh (x, y, z) -> world (y, z, x); x: -> (z, x, y)."""
    axis = up.lstrip("-")
    if up not in ("x", "y", "z", "-x", "-y", "-z"):
        raise ScenarioError(f"scene.object.up must be one of x, y, z, -x, -y, -z, got {up!r}")
    cycle = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0.0]])  # x -> y, y -> z, z -> x
    R = np.linalg.matrix_power(cycle, {"z": 0, "y": 1, "x": 2}[axis])
    if up.startswith("-"):
        R = np.diag([1.0, -1.0, -1.0]) @ R
    return R


def rpy_rotation(rpy_deg) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) (Drake's RollPitchYaw: about the fixed x, y, z axes)."""
    r, p, y = np.radians(np.asarray(rpy_deg, float))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def object_orientation(o: ObjectConfig) -> np.ndarray:
    """The rotation applied before yaw_deg: rpy_deg after up."""
    return rpy_rotation(o.rpy_deg) @ up_rotation(object_up(o))


def build_object(sc: Scenario, check: bool = True) -> ObjectMesh:
    """The object of the scenario in the world frame: scaled (so that the longest side of
    the mesh's own bounding box is `size`, or by `scale`), turned so that its `up` axis
    points up, rotated by `rpy_deg` and then by `yaw_deg` about the vertical, its footprint
    centred at `xy` and its lowest point on its support (scene.support_top()); with
    scene.box_reconstructed, the support box joins it as one more part. Raises if it leaves
    W_box (`check`)."""
    o = sc.scene.object
    if o.kind == "teapot":
        mesh = tessellate_teapot(o.tessellation)
    elif o.kind == "bunny":
        mesh = load_bunny()
    elif o.kind == "dragon":
        mesh = load_dragon()
    elif o.kind in SHAPES:
        mesh = ObjectMesh(*SHAPES[o.kind]())
    else:
        p = Path(o.mesh)
        if not p.is_absolute():
            p = Path(sc.base_dir or ".") / p
        mesh = load_mesh_file(p)
    V = mesh.vertices.copy()
    lo, hi = V.min(axis=0), V.max(axis=0)
    size = object_size(o)
    if size > 0:
        V *= size / float(np.max(hi - lo))
    else:
        V *= 1.0 if o.scale is None else o.scale
    R = object_orientation(o)
    if not np.array_equal(R, np.eye(3)):  # skipped when identity: z-up objects stay bit for bit
        V = V @ R.T
    c, s = math.cos(math.radians(o.yaw_deg)), math.sin(math.radians(o.yaw_deg))
    V = V @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]).T
    lo, hi = V.min(axis=0), V.max(axis=0)
    centre = 0.5 * (lo + hi)
    V += np.array([o.xy[0] - centre[0], o.xy[1] - centre[1], sc.scene.support_top() - lo[2]])
    out = ObjectMesh(V, mesh.triangles, mesh.parts)
    if sc.scene.box_reconstructed:
        out = with_support_box(out, sc.scene)
    if check:
        check_inside_bbox(out, sc)
    return out


def support_box(scene) -> tuple[np.ndarray, np.ndarray]:
    """The support box's (lo, hi) corners: box_size on the floor, centred under the object's xy."""
    x, y = scene.object.xy
    bx, by, bz = scene.box_size
    return np.array([x - bx / 2, y - by / 2, 0.0]), np.array([x + bx / 2, y + by / 2, bz])


def with_support_box(mesh: ObjectMesh, scene) -> ObjectMesh:
    """`mesh` and the support box as one mesh (the box one more part)."""
    V, T = box(*support_box(scene))
    parts = mesh.parts if mesh.parts is not None else np.zeros(len(mesh.triangles), np.int32)
    return ObjectMesh(np.concatenate([mesh.vertices, V]), np.concatenate([mesh.triangles, T + len(mesh.vertices)]),
                      np.concatenate([parts, np.full(len(T), parts.max() + 1, np.int32)]).astype(np.int32))


def automatic_wbox(sc: Scenario) -> tuple[list[float], list[float]]:
    """W_box around what is reconstructed: its bounds grown by scene.bbox_margin on x, y and
    top, the bottom on the surface it stands on (scene.base_z())."""
    lo, hi = build_object(sc, check=False).bounds
    m = sc.scene.bbox_margin
    return ([round(float(lo[0] - m), 4), round(float(lo[1] - m), 4), sc.scene.base_z()],
            [round(float(hi[0] + m), 4), round(float(hi[1] + m), 4), round(float(hi[2] + m), 4)])


def check_inside_bbox(mesh: ObjectMesh, sc: Scenario, tol: float = 1e-6):
    lo, hi = mesh.bounds
    bmin, bmax = np.array(sc.scene.bbox_min), np.array(sc.scene.bbox_max)
    if np.any(lo < bmin - tol) or np.any(hi > bmax + tol):
        raise ScenarioError(
            "the object does not fit in the bounding box W_box: object spans "
            f"{np.round(lo, 3).tolist()}..{np.round(hi, 3).tolist()}, W_box is "
            f"{list(sc.scene.bbox_min)}..{list(sc.scene.bbox_max)}")


def sample_surface(mesh: ObjectMesh, n: int, rng: np.random.Generator) -> np.ndarray:
    """Uniform area-weighted samples on the mesh surface, shape (n, 3)."""
    V, T = mesh.vertices, mesh.triangles
    a, b, c = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    tri = rng.choice(len(T), size=n, p=area / area.sum())
    r1 = np.sqrt(rng.random(n))
    r2 = rng.random(n)
    w0, w1, w2 = 1 - r1, r1 * (1 - r2), r1 * r2
    return w0[:, None] * a[tri] + w1[:, None] * b[tri] + w2[:, None] * c[tri]


def ground_truth_points(mesh: ObjectMesh, sc: Scenario, rng: np.random.Generator | None = None) -> np.ndarray:
    """Ground-truth surface samples for coverage. Samples within `mapper.table_clearance` of
    the table top are left out: that band (and the underside resting on the table) is
    removed from every scan by the cloud filter volume, so no planner can ever cover it.
    rng None: the run's own draw (seeded by the scenario's seed), so a run directory's
    coverage can be recomputed from its scenario.yaml."""
    if rng is None:
        rng = np.random.default_rng([sc.seed, 3])
    n = sc.scene.gt_points
    pts = sample_surface(mesh, 2 * n, rng)
    keep = pts[:, 2] >= sc.scene.base_z() + sc.mapper.table_clearance
    pts = pts[keep]
    return pts[:n]
