"""A free-space certificate in front of Drake's collision checks: a numba kernel that proves a
robot state collision free (or in collision) from conservative models of the robot's collision
geometry, so that Drake (`SceneGraphCollisionChecker`) is asked only about the states it cannot
decide.

The verdicts are Drake's: a state is reported free without Drake only when every pair that
Drake would check is separated by more than its padding plus `EPS` in the conservative model,
where Drake would find it free too; it is reported in collision only when a ball inside a robot
cylinder reaches more than `EPS` into an environment Box that Drake checks it against, or into
another robot geometry of a pair Drake checks (a ball inside it, or its exact vertical
cylinder); every other state goes to Drake. The model of the free test:

- each robot collision cylinder whose axis stays vertical for every state (the PatrolBot's body
  and pedestal, the Katana's first link) is kept exact, and is tested exactly against an
  environment box that is only turned about z (the distance of two products, disc x interval
  and rectangle x interval, is the root of the sums of their squared 2-D and 1-D distances);
- every other robot cylinder (the arm's links, the camera housing) is covered by spheres along
  its axis (n = ceil(L / r) spheres of radius sqrt(r^2 + (L / 2n)^2), which contain it), and
  is tested against each environment geometry's oriented bounding box (the object's mesh: the
  box of its convex hull, which is what Drake checks of a mesh);
- robot pairs that the checker filters (adjacent links) are skipped, as Drake skips them.

Most states of a tree or a rollout are far from the table, the walls and W_box, and each costs
a few us here against ~25-200 us in Drake (`nbvs bench collision`).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..world.robot import _X

#: a pair counts as separated only beyond its padding plus this margin (m): rounding of the two
#: forward kinematics (this module's and Drake's) is ~1e-15 m
EPS = 1e-5
FREE, COLLIDING, UNKNOWN = 1, 0, -1  #: `FreeCertificate.classify`'s verdicts
ROBOT_BODIES = ("base_link", "katana_link1", "katana_link2", "katana_link3", "katana_link4", "katana_link5")


class Unsupported(Exception):
    """The robot or the environment has geometry this model does not cover (the collision model
    then asks Drake about every state)."""


def _cylinder_spheres(r: float, length: float):
    n = max(1, math.ceil(length / r))
    z = -length / 2 + (np.arange(n) + 0.5) * length / n
    return np.stack([np.zeros(n), np.zeros(n), z], axis=1), math.sqrt(r * r + (length / (2 * n)) ** 2)


def _env_box(shape, X_WG: np.ndarray):
    """(R (3, 3), centre (3,), half extents (3,)) of a box that contains the shape."""
    from pydrake.geometry import Box, Convex, Cylinder, Mesh, Sphere
    R, p = X_WG[:3, :3], X_WG[:3, 3]
    if isinstance(shape, Box):
        return R, p, np.array([shape.width(), shape.depth(), shape.height()]) / 2
    if isinstance(shape, Sphere):
        return R, p, np.full(3, shape.radius())
    if isinstance(shape, Cylinder):
        return R, p, np.array([shape.radius(), shape.radius(), shape.length() / 2])
    if isinstance(shape, (Mesh, Convex)):
        hull = shape.GetConvexHull()
        v = np.array([hull.vertex(i) for i in range(hull.num_vertices())])
        lo, hi = v.min(axis=0), v.max(axis=0)
        return R, p + R @ ((lo + hi) / 2), (hi - lo) / 2
    raise Unsupported(f"environment shape {type(shape).__name__}")


class FreeCertificate:
    """The conservative models of one collision checker's world (`CollisionModel`):
    `classify(q)` gives each state (N, 8) FREE, COLLIDING or UNKNOWN (ask Drake)."""

    def __init__(self, diagram, checker, kin):
        from pydrake.geometry import Box, Cylinder, Sphere

        from ..world.robot import ARM_JOINTS  # kin.joint_fixed holds their (X_PF, axis): base_link -> ... -> link5
        plant, sg = diagram.plant(), diagram.scene_graph()
        inspector = sg.model_inspector()
        bodies = [plant.GetBodyByName(n) for n in ROBOT_BODIES]
        for i, jn in enumerate(ARM_JOINTS):
            j = plant.GetJointByName(jn)
            if j.parent_body().name() != ROBOT_BODIES[i] or j.child_body().name() != ROBOT_BODIES[i + 1]:
                raise Unsupported(f"joint {jn} is not between {ROBOT_BODIES[i]} and {ROBOT_BODIES[i + 1]}")
        robot_index = {b.index() for b in bodies}
        instance = bodies[0].model_instance()
        for bi in range(plant.num_bodies()):
            b = plant.get_body(_body_index(bi))
            if (b.model_instance() == instance and b.index() not in robot_index
                    and plant.GetCollisionGeometriesForBody(b)):
                raise Unsupported(f"robot body {b.name()} has collision geometry")
            if (b.model_instance() != instance and b.index() != plant.world_body().index()
                    and plant.GetCollisionGeometriesForBody(b)):
                raise Unsupported(f"environment body {b.name()} is not the world body")
        g_body, g_X, g_r, g_h, g_bound, g_cyl, s_geom, s_c, s_rho, s_in = [], [], [], [], [], [], [], [], [], []
        for k, b in enumerate(bodies):
            for gid in plant.GetCollisionGeometriesForBody(b):
                shape, X_BG = inspector.GetShape(gid), _X(inspector.GetPoseInFrame(gid))
                if isinstance(shape, Cylinder):
                    r, h = shape.radius(), shape.length() / 2
                    centres, rho = _cylinder_spheres(r, shape.length())
                    inner = min(r, shape.length() / (2 * len(centres)))  # a ball inside the cylinder
                elif isinstance(shape, Sphere):
                    r, h = shape.radius(), 0.0
                    centres, rho = np.zeros((1, 3)), r
                    inner = r
                else:
                    raise Unsupported(f"robot shape {type(shape).__name__}")
                g = len(g_body)
                g_body.append(k)
                g_X.append(X_BG)
                g_r.append(r)
                g_h.append(h)
                g_bound.append(math.hypot(r, h))
                g_cyl.append(isinstance(shape, Cylinder))
                s_geom += [g] * len(centres)
                s_c += list(centres)
                s_rho += [rho] * len(centres)
                s_in += [inner] * len(centres)
        self.g_body = np.array(g_body, np.int64)
        self.g_X = np.array(g_X)
        self.g_r, self.g_h, self.g_bound = np.array(g_r), np.array(g_h), np.array(g_bound)
        self.s_geom, self.s_c, self.s_rho = np.array(s_geom, np.int64), np.array(s_c), np.array(s_rho)
        self.s_in = np.array(s_in)  #: radius of the ball about each sphere's centre inside the geometry
        self.X_PF = np.array([X for X, _ in kin.joint_fixed])
        self.axes = np.array([a / np.linalg.norm(a) for _, a in kin.joint_fixed])
        # cylinders whose axis stays vertical: checked at random states (the set of states where
        # a chain of rotations keeps an axis vertical is all of them or of measure zero)
        rng = np.random.default_rng(0)
        qs = np.zeros((16, 8))
        qs[:, 2] = rng.uniform(-np.pi, np.pi, 16)
        qs[:, 3:] = rng.uniform(kin.arm_lower, kin.arm_upper, (16, 5))
        R = np.stack([self.geometry_poses(q)[:, :3, 2] for q in qs])  # (16, G, 3) axes
        self.g_vert = np.array(g_cyl, bool) & np.all(np.abs(R[:, :, 2]) > 1 - 1e-12, axis=0)
        # ... and keep their height: a chain of turns that keeps an axis vertical turns about
        # vertical axes only (`free_margins` relies on it: planar motion leaves their vertical gaps)
        z = np.stack([self.geometry_poses(q)[:, 2, 3] for q in qs])
        self.g_vert &= np.ptp(z, axis=0) < 1e-12
        world = plant.world_body()
        e_R, e_p, e_h, e_pad, e_exact = [], [], [], [], []
        for gid in plant.GetCollisionGeometriesForBody(world):
            R_, p_, h_ = _env_box(inspector.GetShape(gid), _X(inspector.GetPoseInFrame(gid)))
            e_exact.append(isinstance(inspector.GetShape(gid), Box))
            e_R.append(R_)
            e_p.append(p_)
            e_h.append(h_)
        self.e_R = np.array(e_R).reshape(-1, 3, 3)
        self.e_p, self.e_h = np.array(e_p).reshape(-1, 3), np.array(e_h).reshape(-1, 3)
        self.e_exact = np.array(e_exact, bool)  #: the box is the geometry (not a box around it)
        self.e_zal = np.abs(self.e_R[:, 2, 2]) > 1 - 1e-12 if len(e_R) else np.zeros(0, bool)
        for b in bodies:
            e_pad.append(checker.GetPaddingBetween(b, world) if not checker.IsCollisionFilteredBetween(b, world)
                         else -np.inf)
        self.g_pad = np.array([e_pad[k] for k in g_body])  # -inf: filtered against the environment
        pairs, pads = [], []
        for a in range(len(g_body)):
            for c in range(a + 1, len(g_body)):
                ba, bc = bodies[g_body[a]], bodies[g_body[c]]
                if g_body[a] != g_body[c] and not checker.IsCollisionFilteredBetween(ba, bc):
                    pairs.append((a, c))
                    pads.append(checker.GetPaddingBetween(ba, bc))
        self.pairs = np.array(pairs, np.int64).reshape(-1, 2)
        self.pair_pad = np.array(pads, float)
        self.s0 = _sphere_starts(self.s_geom, len(self.g_body))
        #: the arrays the numba kernels take, packed (`pack_model`; `unpack` in the kernels)
        self.model = pack_model({name: getattr(self, name) for name in MODEL_ARRAYS})
        #: the length of a state's margins (`margin_size`)
        self.margin_size = margin_size(unpack(*self.model))

    def geometry_poses(self, q: np.ndarray) -> np.ndarray:
        """X_WG (G, 4, 4) of the robot's collision geometries at the state q (8,)."""
        T = _body_poses(np.asarray(q, float), self.X_PF, self.axes)
        return np.einsum("gij,gjk->gik", T[self.g_body], self.g_X)

    def body_poses(self, q: np.ndarray) -> np.ndarray:
        """X_WB (6, 4, 4) of ROBOT_BODIES at the state q (8,)."""
        return _body_poses(np.asarray(q, float), self.X_PF, self.axes)

    def classify(self, q: np.ndarray) -> np.ndarray:
        """int8 (N,) for states (N, 8): FREE (proved collision free), COLLIDING (a ball inside a
        robot geometry reaches into an environment box that Drake checks it against, or into
        the other geometry of a robot pair Drake checks, deeper than EPS: `_pair_overlaps`) or
        UNKNOWN (ask Drake)."""
        q = np.ascontiguousarray(np.atleast_2d(q), dtype=np.float64)
        out = np.full(len(q), UNKNOWN, np.int8)
        _certify(q, *self.model, out)
        return out

    def free(self, q: np.ndarray) -> np.ndarray:
        """True for the states (N, 8) proved collision free."""
        return self.classify(q) == FREE

    def n_parts(self) -> int:
        """The parts of `part_clearances`: the spheres of the non-vertical geometries and the
        vertical cylinders."""
        return int(np.sum(self.g_vert)) + int(np.sum(~self.g_vert[self.s_geom]))

    def part_clearances(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(c, r), each (N, parts), of `_part_clearances` at states (N, 8)."""
        q = np.ascontiguousarray(np.atleast_2d(q), dtype=np.float64)
        c, r = np.empty((len(q), self.n_parts())), np.empty((len(q), self.n_parts()))
        _part_clearances(q, *self.model, c, r, np.empty((0, 0, 0)))
        return c, r

    def part_box_clearances(self, q: np.ndarray):
        """(c, r, slack) at states (N, 8): `part_clearances`' c and r, and per part the
        clearance from each of the environment's boxes (slack (N, parts, boxes); c is its
        minimum): a planar rigid motion that moves part j by less than slack[n, j, m] keeps it
        clear of box m (`path_verdicts.rollout_verdicts` tests a part only against the boxes it
        may reach)."""
        q = np.ascontiguousarray(np.atleast_2d(q), dtype=np.float64)
        P, M = self.n_parts(), len(self.e_p)
        c, r, slack = np.empty((len(q), P)), np.empty((len(q), P)), np.empty((len(q), P, M))
        _part_clearances(q, *self.model, c, r, slack)
        return c, r, slack


def _body_index(i: int):
    from pydrake.multibody.tree import BodyIndex
    return BodyIndex(i)


@nb.njit(cache=True)
def _mul(A, B, out):
    """out = A @ B for 4x4 rigid transforms (last row 0 0 0 1)."""
    for i in range(3):
        for j in range(4):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
        out[i, 3] += A[i, 3]
    out[3, 0] = out[3, 1] = out[3, 2] = 0.0
    out[3, 3] = 1.0


@nb.njit(cache=True)
def _rot(axis, angle, out):
    """out = the 4x4 rotation about a unit axis (Rodrigues), as robot._axis_rotation."""
    k0, k1, k2 = axis[0], axis[1], axis[2]
    s, c = math.sin(angle), math.cos(angle)
    v = 1.0 - c
    out[:] = 0.0
    out[0, 0] = 1.0 + v * (-k2 * k2 - k1 * k1)
    out[0, 1] = -s * k2 + v * k0 * k1
    out[0, 2] = s * k1 + v * k0 * k2
    out[1, 0] = s * k2 + v * k0 * k1
    out[1, 1] = 1.0 + v * (-k2 * k2 - k0 * k0)
    out[1, 2] = -s * k0 + v * k1 * k2
    out[2, 0] = -s * k1 + v * k0 * k2
    out[2, 1] = s * k0 + v * k1 * k2
    out[2, 2] = 1.0 + v * (-k1 * k1 - k0 * k0)
    out[3, 3] = 1.0


@nb.njit(cache=True)
def _body_poses_into(q, X_PF, axes, T, tmp, rot):
    c, s = math.cos(q[2]), math.sin(q[2])
    T[0] = 0.0
    T[0, 0, 0], T[0, 0, 1], T[0, 1, 0], T[0, 1, 1] = c, -s, s, c
    T[0, 2, 2] = T[0, 3, 3] = 1.0
    T[0, 0, 3], T[0, 1, 3] = q[0], q[1]
    for i in range(5):
        _mul(T[i], X_PF[i], tmp)
        _rot(axes[i], q[3 + i], rot)
        _mul(tmp, rot, T[i + 1])


@nb.njit(cache=True)
def _body_poses(q, X_PF, axes):
    T = np.empty((6, 4, 4))
    _body_poses_into(q, X_PF, axes, T, np.empty((4, 4)), np.empty((4, 4)))
    return T


@nb.njit(cache=True, inline="always")
def point_box(px, py, pz, e_R, e_p, e_h, m):
    """Distance from a point to the oriented box m (e_R[m]: its axes as columns). Scalar
    indexing throughout: a sub-array view costs numba a reference count per use."""
    dx, dy, dz = px - e_p[m, 0], py - e_p[m, 1], pz - e_p[m, 2]
    sq = 0.0
    for i in range(3):
        e = abs(e_R[m, 0, i] * dx + e_R[m, 1, i] * dy + e_R[m, 2, i] * dz) - e_h[m, i]
        if e > 0:
            sq += e * e
    return math.sqrt(sq)


@nb.njit(cache=True, inline="always")
def vertical_cylinder_box(px, py, pz, r, hh, e_R, e_p, e_h, m):
    """Distance from a vertical cylinder (centre, radius r, half length hh) to the box m, turned
    only about z: exact (disc x interval against rectangle x interval)."""
    dx, dy, dz = px - e_p[m, 0], py - e_p[m, 1], pz - e_p[m, 2]
    lx = e_R[m, 0, 0] * dx + e_R[m, 1, 0] * dy
    ly = e_R[m, 0, 1] * dx + e_R[m, 1, 1] * dy
    ex = max(abs(lx) - e_h[m, 0], 0.0)
    ey = max(abs(ly) - e_h[m, 1], 0.0)
    gxy = max(math.sqrt(ex * ex + ey * ey) - r, 0.0)
    gz = max(abs(dz) - e_h[m, 2] - hh, 0.0)
    return math.sqrt(gxy * gxy + gz * gz)


@nb.njit(cache=True, inline="always")
def vertical_cylinder_box_overlap(px, py, pz, r, hh, e_R, e_p, e_h, m, s):
    """Whether the vertical cylinder and the box m (turned about z), each shrunk by s on every
    side, still overlap (then the two reach s or more into each other)."""
    dx, dy, dz = px - e_p[m, 0], py - e_p[m, 1], pz - e_p[m, 2]
    lx = e_R[m, 0, 0] * dx + e_R[m, 1, 0] * dy
    ly = e_R[m, 0, 1] * dx + e_R[m, 1, 1] * dy
    ex = max(abs(lx) - (e_h[m, 0] - s), 0.0)
    ey = max(abs(ly) - (e_h[m, 1] - s), 0.0)
    return math.sqrt(ex * ex + ey * ey) < r - s and abs(dz) < e_h[m, 2] + hh - 2 * s


@nb.njit(cache=True, inline="always")
def _point_vertical_cylinder(px, py, pz, cx, cy, cz, r, hh):
    gr = max(math.sqrt((px - cx) ** 2 + (py - cy) ** 2) - r, 0.0)
    gz = max(abs(pz - cz) - hh, 0.0)
    return math.sqrt(gr * gr + gz * gz)


def _sphere_starts(s_geom: np.ndarray, n_geom: int) -> np.ndarray:
    """s0 (G + 1,): the spheres of geometry g are s0[g]:s0[g + 1] (they are appended in order)."""
    return np.concatenate([[0], np.cumsum(np.bincount(s_geom, minlength=n_geom))]).astype(np.int64)


#: the model's arrays in the order the kernels take them; those in MODEL_INTS are stored as int64
MODEL_ARRAYS = ("X_PF", "axes", "g_body", "g_X", "g_vert", "g_r", "g_h", "g_bound", "g_pad", "s0", "s_geom", "s_c",
                "s_rho", "s_in", "e_R", "e_p", "e_h", "e_zal", "e_exact", "pairs", "pair_pad")
MODEL_INTS = frozenset(("g_body", "g_vert", "s0", "s_geom", "e_zal", "e_exact", "pairs"))


def pack_model(arrays: dict) -> tuple:
    """The model's arrays packed into (F float64, I int64, H int64 (21, 4): offset and shape of
    each), passed to the kernels as three array arguments: numba types arrays fast and tuples
    slowly (a call with the 21 arrays as a tuple cost ~12 us)."""
    F, I, H = [], [], np.zeros((len(MODEL_ARRAYS), 4), np.int64)
    nf = ni = 0
    for k, name in enumerate(MODEL_ARRAYS):
        a = np.asarray(arrays[name])
        is_int = name in MODEL_INTS
        flat = np.ascontiguousarray(a, np.int64 if is_int else np.float64).reshape(-1)
        H[k, 0] = ni if is_int else nf
        H[k, 1:1 + a.ndim] = a.shape
        (I if is_int else F).append(flat)
        if is_int:
            ni += len(flat)
        else:
            nf += len(flat)
    return (np.concatenate(F) if F else np.zeros(0), np.concatenate(I) if I else np.zeros(0, np.int64), H)


@nb.njit(cache=True)
def unpack(F, I, H):
    """The 21 model arrays (views) of a packed model (`pack_model`)."""
    X_PF = F[H[0, 0]:H[0, 0] + H[0, 1] * H[0, 2] * H[0, 3]].reshape((H[0, 1], H[0, 2], H[0, 3]))
    axes = F[H[1, 0]:H[1, 0] + H[1, 1] * H[1, 2]].reshape((H[1, 1], H[1, 2]))
    g_body = I[H[2, 0]:H[2, 0] + H[2, 1]]
    g_X = F[H[3, 0]:H[3, 0] + H[3, 1] * H[3, 2] * H[3, 3]].reshape((H[3, 1], H[3, 2], H[3, 3]))
    g_vert = I[H[4, 0]:H[4, 0] + H[4, 1]]
    g_r = F[H[5, 0]:H[5, 0] + H[5, 1]]
    g_h = F[H[6, 0]:H[6, 0] + H[6, 1]]
    g_bound = F[H[7, 0]:H[7, 0] + H[7, 1]]
    g_pad = F[H[8, 0]:H[8, 0] + H[8, 1]]
    s0 = I[H[9, 0]:H[9, 0] + H[9, 1]]
    s_geom = I[H[10, 0]:H[10, 0] + H[10, 1]]
    s_c = F[H[11, 0]:H[11, 0] + H[11, 1] * H[11, 2]].reshape((H[11, 1], H[11, 2]))
    s_rho = F[H[12, 0]:H[12, 0] + H[12, 1]]
    s_in = F[H[13, 0]:H[13, 0] + H[13, 1]]
    e_R = F[H[14, 0]:H[14, 0] + H[14, 1] * H[14, 2] * H[14, 3]].reshape((H[14, 1], H[14, 2], H[14, 3]))
    e_p = F[H[15, 0]:H[15, 0] + H[15, 1] * H[15, 2]].reshape((H[15, 1], H[15, 2]))
    e_h = F[H[16, 0]:H[16, 0] + H[16, 1] * H[16, 2]].reshape((H[16, 1], H[16, 2]))
    e_zal = I[H[17, 0]:H[17, 0] + H[17, 1]]
    e_exact = I[H[18, 0]:H[18, 0] + H[18, 1]]
    pairs = I[H[19, 0]:H[19, 0] + H[19, 1] * H[19, 2]].reshape((H[19, 1], H[19, 2]))
    pair_pad = F[H[20, 0]:H[20, 0] + H[20, 1]]
    return (X_PF, axes, g_body, g_X, g_vert, g_r, g_h, g_bound, g_pad, s0, s_geom, s_c, s_rho, s_in, e_R, e_p, e_h,
            e_zal, e_exact, pairs, pair_pad)


@nb.njit(cache=True)
def robot_scratch(model):
    """Work arrays of `pose_robot` for one model: (geometry poses, their centres, sphere centres,
    body poses, two 4x4 temporaries)."""
    G, S = model[2].shape[0], model[10].shape[0]
    return (np.empty((G, 4, 4)), np.empty((G, 3)), np.empty((S, 3)), np.empty((6, 4, 4)), np.empty((4, 4)),
            np.empty((4, 4)))


@nb.njit(cache=True, inline="always")
def body_chain(qn, X_PF, axes, T, tmp):
    """T[0..5] = the poses of ROBOT_BODIES at the state qn (8,): `_body_poses_into`'s
    arithmetic, written with scalar indexing (no sub-array views); tmp (4, 4) is scratch."""
    c, s = math.cos(qn[2]), math.sin(qn[2])
    for i in range(4):
        for j in range(4):
            T[0, i, j] = 0.0
    T[0, 0, 0], T[0, 0, 1], T[0, 1, 0], T[0, 1, 1] = c, -s, s, c
    T[0, 2, 2] = T[0, 3, 3] = 1.0
    T[0, 0, 3], T[0, 1, 3] = qn[0], qn[1]
    for b in range(5):
        for i in range(3):  # tmp = T[b] @ X_PF[b]
            for j in range(4):
                tmp[i, j] = T[b, i, 0] * X_PF[b, 0, j] + T[b, i, 1] * X_PF[b, 1, j] + T[b, i, 2] * X_PF[b, 2, j]
            tmp[i, 3] += T[b, i, 3]
        k0, k1, k2 = axes[b, 0], axes[b, 1], axes[b, 2]  # the rotation of `_rot`
        sn, cs = math.sin(qn[3 + b]), math.cos(qn[3 + b])
        v = 1.0 - cs
        r00 = 1.0 + v * (-k2 * k2 - k1 * k1)
        r01 = -sn * k2 + v * k0 * k1
        r02 = sn * k1 + v * k0 * k2
        r10 = sn * k2 + v * k0 * k1
        r11 = 1.0 + v * (-k2 * k2 - k0 * k0)
        r12 = -sn * k0 + v * k1 * k2
        r20 = -sn * k1 + v * k0 * k2
        r21 = sn * k0 + v * k1 * k2
        r22 = 1.0 + v * (-k1 * k1 - k0 * k0)
        for i in range(3):  # T[b + 1] = tmp @ rot (as `_mul`: the zero terms included)
            T[b + 1, i, 0] = tmp[i, 0] * r00 + tmp[i, 1] * r10 + tmp[i, 2] * r20
            T[b + 1, i, 1] = tmp[i, 0] * r01 + tmp[i, 1] * r11 + tmp[i, 2] * r21
            T[b + 1, i, 2] = tmp[i, 0] * r02 + tmp[i, 1] * r12 + tmp[i, 2] * r22
            T[b + 1, i, 3] = (tmp[i, 0] * 0.0 + tmp[i, 1] * 0.0 + tmp[i, 2] * 0.0) + tmp[i, 3]
        T[b + 1, 3, 0] = T[b + 1, 3, 1] = T[b + 1, 3, 2] = 0.0
        T[b + 1, 3, 3] = 1.0


@nb.njit(cache=True, inline="always")
def pose_robot(qn, model, scratch):
    """Fills scratch with the robot's geometry poses (XG), their centres (gp) and the sphere
    centres (sw) at the state qn (8,): `_body_poses_into` and the geometry and sphere
    transforms, with the same arithmetic, written with scalar indexing (no sub-array views)."""
    X_PF, axes, g_body, g_X, s_geom, s_c = model[0], model[1], model[2], model[3], model[10], model[11]
    XG, gp, sw, T, tmp, rot = scratch
    body_chain(qn, X_PF, axes, T, tmp)
    for g in range(g_body.shape[0]):
        a = g_body[g]
        for i in range(3):
            for j in range(4):
                XG[g, i, j] = T[a, i, 0] * g_X[g, 0, j] + T[a, i, 1] * g_X[g, 1, j] + T[a, i, 2] * g_X[g, 2, j]
            XG[g, i, 3] += T[a, i, 3]
            gp[g, i] = XG[g, i, 3]
    for k in range(s_geom.shape[0]):
        g = s_geom[k]
        for i in range(3):
            sw[k, i] = XG[g, i, 0] * s_c[k, 0] + XG[g, i, 1] * s_c[k, 1] + XG[g, i, 2] * s_c[k, 2] + XG[g, i, 3]


@nb.njit(cache=True, inline="always")
def _pair_gap(a, c, gp, sw, g_vert, g_r, g_h, s0, rad, stop):
    """A bound of the distance between robot geometries a and c at the posed state
    (`pose_robot`'s gp, sw) in a model whose spheres have the radii `rad` (s_rho: balls that
    contain the geometry, so a lower bound; s_in: balls inside it, so an upper bound, negative
    when they overlap). Two vertical cylinders are exact (negative: the least overlap, in x-y
    or in z). Stops at the first sphere term below `stop`."""
    if g_vert[a] and g_vert[c]:
        ox = g_r[a] + g_r[c] - math.sqrt((gp[a, 0] - gp[c, 0]) ** 2 + (gp[a, 1] - gp[c, 1]) ** 2)
        oz = g_h[a] + g_h[c] - abs(gp[a, 2] - gp[c, 2])
        if ox > 0.0 and oz > 0.0:
            return -min(ox, oz)
        gxy, gz = max(-ox, 0.0), max(-oz, 0.0)
        return math.sqrt(gxy * gxy + gz * gz)
    if g_vert[c]:  # the vertical one as `a`
        a, c = c, a
    best = np.inf
    for k in range(s0[c], s0[c + 1]):
        if g_vert[a]:
            best = min(best, _point_vertical_cylinder(sw[k, 0], sw[k, 1], sw[k, 2], gp[a, 0], gp[a, 1], gp[a, 2],
                                                      g_r[a], g_h[a]) - rad[k])
        else:
            for k2 in range(s0[a], s0[a + 1]):
                best = min(best, math.sqrt((sw[k, 0] - sw[k2, 0]) ** 2 + (sw[k, 1] - sw[k2, 1]) ** 2
                                           + (sw[k, 2] - sw[k2, 2]) ** 2) - rad[k] - rad[k2])
        if best < stop:
            return best
    return best


@nb.njit(cache=True, inline="always")
def _pair_overlaps(gp, sw, g_vert, g_r, g_h, g_bound, s0, s_in, pairs, pair_pad):
    """Whether some robot pair that Drake checks (padding >= 0) is proved in collision at the
    posed state: in the inner model (balls inside the geometries, the vertical cylinders
    exact) the two reach more than EPS into each other (`_pair_gap`)."""
    for j in range(pairs.shape[0]):
        if not pair_pad[j] >= 0.0:
            continue
        a, c = pairs[j, 0], pairs[j, 1]
        if math.sqrt((gp[a, 0] - gp[c, 0]) ** 2 + (gp[a, 1] - gp[c, 1]) ** 2
                     + (gp[a, 2] - gp[c, 2]) ** 2) >= g_bound[a] + g_bound[c]:
            continue  # their bounding balls are apart
        if _pair_gap(a, c, gp, sw, g_vert, g_r, g_h, s0, s_in, -EPS) < -EPS:
            return True
    return False


@nb.njit(cache=True)
def classify_state(qn, model, scratch) -> int:
    """FREE, COLLIDING or UNKNOWN for one state qn (8,) (see `FreeCertificate.classify`)."""
    (X_PF, axes, g_body, g_X, g_vert, g_r, g_h, g_bound, g_pad, s0, s_geom, s_c, s_rho, s_in, e_R, e_p, e_h, e_zal,
     e_exact, pairs, pair_pad) = model
    G, M, P = g_body.shape[0], e_p.shape[0], pairs.shape[0]
    pose_robot(qn, model, scratch)
    gp, sw = scratch[1], scratch[2]
    # a ball inside a robot geometry reaches into an environment box (padding >= 0)
    for g in range(G):
        if not g_pad[g] >= 0.0:
            continue
        for m in range(M):
            if not e_exact[m] or point_box(gp[g, 0], gp[g, 1], gp[g, 2], e_R, e_p, e_h, m) >= g_bound[g]:
                continue
            if g_vert[g] and e_zal[m] and vertical_cylinder_box_overlap(
                    gp[g, 0], gp[g, 1], gp[g, 2], g_r[g], g_h[g], e_R, e_p, e_h, m, EPS):
                return COLLIDING
            for k in range(s0[g], s0[g + 1]):
                if point_box(sw[k, 0], sw[k, 1], sw[k, 2], e_R, e_p, e_h, m) < s_in[k] - EPS:
                    return COLLIDING
    if _pair_overlaps(gp, sw, g_vert, g_r, g_h, g_bound, s0, s_in, pairs, pair_pad):
        return COLLIDING
    for g in range(G):
        pad = g_pad[g]
        if pad == -np.inf:
            continue
        for m in range(M):
            d = point_box(gp[g, 0], gp[g, 1], gp[g, 2], e_R, e_p, e_h, m)
            if d > g_bound[g] + pad + EPS:
                continue
            if g_vert[g] and e_zal[m]:
                if vertical_cylinder_box(gp[g, 0], gp[g, 1], gp[g, 2], g_r[g], g_h[g], e_R, e_p, e_h, m) <= pad + EPS:
                    return UNKNOWN
                continue
            for k in range(s0[g], s0[g + 1]):
                if point_box(sw[k, 0], sw[k, 1], sw[k, 2], e_R, e_p, e_h, m) <= s_rho[k] + pad + EPS:
                    return UNKNOWN
    for j in range(P):
        a, c = pairs[j, 0], pairs[j, 1]
        pad = pair_pad[j]
        dd = math.sqrt((gp[a, 0] - gp[c, 0]) ** 2 + (gp[a, 1] - gp[c, 1]) ** 2 + (gp[a, 2] - gp[c, 2]) ** 2)
        if dd > g_bound[a] + g_bound[c] + pad + EPS:
            continue
        if _pair_gap(a, c, gp, sw, g_vert, g_r, g_h, s0, s_rho, pad + EPS) <= pad + EPS:
            return UNKNOWN
    return FREE


@nb.njit(cache=True)
def geometry_reaches(model):
    """((G, 5), (G,)): for each robot geometry, how far joint k moves any point of it per
    radian (0 for the joints after its body: joint k turns body k + 1 and the bodies after it),
    and how far any point of it can be from the base's origin: the chain's link offsets (URDF
    child frames sit at the link origins) plus the geometry's centre offset and bounding
    radius."""
    X_PF, g_body, g_X, g_bound = model[0], model[2], model[3], model[7]
    link = np.empty(5)
    for i in range(5):
        link[i] = math.sqrt(X_PF[i, 0, 3] ** 2 + X_PF[i, 1, 3] ** 2 + X_PF[i, 2, 3] ** 2)
    G = g_body.shape[0]
    GW, base = np.zeros((G, 5)), np.zeros(G)
    for g in range(G):
        b = g_body[g]
        own = math.sqrt(g_X[g, 0, 3] ** 2 + g_X[g, 1, 3] ** 2 + g_X[g, 2, 3] ** 2) + g_bound[g]
        base[g] = own
        for i in range(b):
            base[g] += link[i]
        for k in range(b):
            GW[g, k] = own
            for i in range(k + 1, b):
                GW[g, k] += link[i]
    return GW, base


@nb.njit(cache=True)
def model_reach(model):
    """Motion bounds of the robot's collision geometry (6,): [R_base, R_1, ..., R_5], where
    R_base bounds the distance of any point of any geometry from the base's origin (so from its
    vertical axis) and R_k the distance from arm joint k's origin (the origin of the body it
    turns) of any point of a geometry it moves, at any state (`geometry_reaches`'s largest).
    Moving linearly in state space between two states moves no point of the robot more than
    hypot(dx, dy) + R_base |dtheta| + sum_k R_k |dq_k|; `path_verdicts._walk` uses the state's own
    radius (`free_margins`) in place of R_base, and `arm_motion_bound` the sum over the
    joints."""
    GW, base = geometry_reaches(model)
    out = np.zeros(6)
    for g in range(GW.shape[0]):
        out[0] = max(out[0], base[g])
        for k in range(5):
            out[1 + k] = max(out[1 + k], GW[g, k])
    return out


@nb.njit(cache=True)
def pair_reaches(model):
    """(P, 5): for each robot pair (geometries a, c on bodies b_a <= b_c), how far joint k can
    move a point of the pair's second geometry relative to the first per radian
    (`geometry_reaches` of c) for the joints between the two bodies (b_a <= k < b_c), 0 for the
    others, which move both alike. sum_k W[j, k] |dq_k| bounds the pair's relative motion
    along a straight line in state space, and is at most `arm_motion_bound`'s."""
    g_body, pairs = model[2], model[19]
    GW = geometry_reaches(model)[0]
    W = np.zeros((pairs.shape[0], 5))
    for j in range(pairs.shape[0]):
        a, c = pairs[j, 0], pairs[j, 1]
        if g_body[a] > g_body[c]:
            a, c = c, a
        for k in range(g_body[a], g_body[c]):
            W[j, k] = GW[c, k]
    return W


@nb.njit(cache=True, inline="always")
def arm_motion_bound(a, b, reach):
    """An upper bound of how far any point of the robot moves relative to any other between the
    states a and b, along the straight line between them in state space (the base's motion
    moves them all alike): sum_k R_k |dq_k| (`model_reach`)."""
    m = 0.0
    for k in range(5):
        m += reach[1 + k] * abs(b[3 + k] - a[3 + k])
    return m


@nb.njit(cache=True)
def margin_size(model) -> int:
    """The length of a state's margins as `path_verdicts._walk` keeps them: m_env, m_self, radius
    (`free_margins`), then the P pairs' clearances, the G geometries' clearances and their
    radii."""
    return 3 + model[19].shape[0] + 2 * model[2].shape[0]


@nb.njit(cache=True)
def free_margins(qn, model, scratch, pair_c, geo_c, geo_r):
    """(m_env, m_self, radius): how far, at least, every point of the robot could move at the
    state qn (8,), and every point relative to every other (`arm_motion_bound`), with
    the state still FREE by `classify_state`'s tests, the same tests with the same thresholds:
    the least clearance beyond its padding (and EPS) of every robot geometry to every
    environment box, and of every robot pair Drake checks. Both > 0 prove the state FREE;
    otherwise it says nothing (ask `classify_state`). Bounding spheres first: a finer test
    runs only when a bound is not positive. The vertical cylinders keep their height
    (`FreeCertificate`), so a vertical gap to a box turned only about z never shrinks.
    radius: the largest horizontal distance of a point of the robot from the base's vertical
    axis at qn (a turn of the base by dtheta moves no point further than radius |dtheta|).
    Where both margins are > 0 it also fills each robot pair's own clearance in pair_c (P,),
    each geometry's clearance to the environment in geo_c (G,) and its radius in geo_r (G,)
    (m_env and m_self are their least, radius their largest): pair j stays clear while the
    motion of its second geometry relative to its first stays below pair_c[j] (`pair_reaches`),
    geometry g while its own motion stays below geo_c[g] (`geometry_reaches`)."""
    (X_PF, axes, g_body, g_X, g_vert, g_r, g_h, g_bound, g_pad, s0, s_geom, s_c, s_rho, s_in, e_R, e_p, e_h, e_zal,
     e_exact, pairs, pair_pad) = model
    G, M, P = g_body.shape[0], e_p.shape[0], pairs.shape[0]
    pose_robot(qn, model, scratch)
    gp, sw = scratch[1], scratch[2]
    best = np.inf
    for g in range(G):
        pad = g_pad[g]
        geo_c[g] = np.inf
        if pad == -np.inf:
            continue
        for m in range(M):
            if g_vert[g] and e_zal[m]:
                # the exact distance sqrt(gxy^2 + gz^2) of classify's test; the cylinder keeps its
                # height, so only its horizontal gap gxy can shrink: by at most the motion
                dx, dy, dz = gp[g, 0] - e_p[m, 0], gp[g, 1] - e_p[m, 1], gp[g, 2] - e_p[m, 2]
                lx = e_R[m, 0, 0] * dx + e_R[m, 1, 0] * dy
                ly = e_R[m, 0, 1] * dx + e_R[m, 1, 1] * dy
                ex = max(abs(lx) - e_h[m, 0], 0.0)
                ey = max(abs(ly) - e_h[m, 1], 0.0)
                gxy = max(math.sqrt(ex * ex + ey * ey) - g_r[g], 0.0)
                gz = max(abs(dz) - e_h[m, 2] - g_h[g], 0.0)
                thr = pad + EPS
                if gz > thr:
                    continue  # apart in height whatever the base does
                if math.sqrt(gxy * gxy + gz * gz) <= thr:
                    return -1.0, -1.0, 0.0
                c = gxy - math.sqrt(thr * thr - gz * gz) if thr > 0.0 else gxy
                geo_c[g] = min(geo_c[g], c)
                continue
            c = point_box(gp[g, 0], gp[g, 1], gp[g, 2], e_R, e_p, e_h, m) - g_bound[g] - pad - EPS
            if c >= geo_c[g]:
                continue
            if c <= 0.0:  # classify's finer tests
                c = np.inf
                for k in range(s0[g], s0[g + 1]):
                    c = min(c, point_box(sw[k, 0], sw[k, 1], sw[k, 2], e_R, e_p, e_h, m) - s_rho[k] - pad - EPS)
                if c <= 0.0:
                    return c, c, 0.0
            geo_c[g] = min(geo_c[g], c)
        best = min(best, geo_c[g])
    if best <= 0.0:
        return best, best, 0.0
    own = np.inf
    for j in range(P):
        a, c2 = pairs[j, 0], pairs[j, 1]
        thr = pair_pad[j] + EPS
        dd = math.sqrt((gp[a, 0] - gp[c2, 0]) ** 2 + (gp[a, 1] - gp[c2, 1]) ** 2 + (gp[a, 2] - gp[c2, 2]) ** 2)
        c = dd - g_bound[a] - g_bound[c2] - thr
        if c <= 0.0:  # classify's finer test (its least, where it is > 0)
            c = _pair_gap(a, c2, gp, sw, g_vert, g_r, g_h, s0, s_rho, thr) - thr
            if c <= 0.0:
                return c, c, 0.0
        pair_c[j] = c
        own = min(own, c)
    radius = 0.0
    for g in range(G):
        geo_r[g] = math.hypot(gp[g, 0] - qn[0], gp[g, 1] - qn[1]) + g_bound[g]
        radius = max(radius, geo_r[g])
    return best, own, radius


@nb.njit(cache=True)
def _certify(q, F, I, H, out):
    model = unpack(F, I, H)
    scratch = robot_scratch(model)
    for n in range(q.shape[0]):
        out[n] = classify_state(q[n], model, scratch)


@nb.njit(cache=True)
def _part_clearances(q, F, I, H, c, r, slack):
    """Per part of the robot (each sphere of a geometry that is not a vertical cylinder, then
    each vertical cylinder), at each state q[n]: c[n, j] a lower bound of the part's distance to
    the environment less the padding (inf: filtered against it) and r[n, j] the largest
    horizontal distance of a point of the part from the base's vertical axis. A planar rigid
    motion of the whole robot by (dx, dy, dtheta) about that axis moves no point of part j more
    than hypot(dx, dy) + r_j |dtheta|, so the part stays clear of the environment while that is
    below c_j; the robot's self-distances do not change under such a motion. slack (N, parts,
    boxes), when it has rows: the same bound per environment box (c is its minimum)."""
    model = unpack(F, I, H)
    (X_PF, axes, g_body, g_X, g_vert, g_r, g_h, g_bound, g_pad, s0, s_geom, s_c, s_rho, s_in, e_R, e_p, e_h, e_zal,
     e_exact, pairs, pair_pad) = model
    scratch = robot_scratch(model)
    G, M = g_body.shape[0], e_p.shape[0]
    per_box = slack.shape[0] > 0
    for n in range(q.shape[0]):
        qn = q[n]
        pose_robot(qn, model, scratch)
        gp, sw = scratch[1], scratch[2]
        j = 0
        for g in range(G):
            pad = g_pad[g]
            if g_vert[g]:
                c[n, j] = np.inf
                r[n, j] = math.hypot(gp[g, 0] - qn[0], gp[g, 1] - qn[1]) + g_r[g]
                for m in range(M):
                    if pad == -np.inf:
                        v = np.inf
                    elif e_zal[m]:
                        v = vertical_cylinder_box(gp[g, 0], gp[g, 1], gp[g, 2], g_r[g], g_h[g], e_R, e_p, e_h, m
                                                  ) - pad - EPS
                    else:
                        v = point_box(gp[g, 0], gp[g, 1], gp[g, 2], e_R, e_p, e_h, m) - g_bound[g] - pad - EPS
                    c[n, j] = min(c[n, j], v)
                    if per_box:
                        slack[n, j, m] = v
                j += 1
                continue
            for k in range(s0[g], s0[g + 1]):
                c[n, j] = np.inf
                r[n, j] = math.hypot(sw[k, 0] - qn[0], sw[k, 1] - qn[1]) + s_rho[k]
                for m in range(M):
                    if pad == -np.inf:
                        v = np.inf
                    else:
                        v = point_box(sw[k, 0], sw[k, 1], sw[k, 2], e_R, e_p, e_h, m) - s_rho[k] - pad - EPS
                    c[n, j] = min(c[n, j], v)
                    if per_box:
                        slack[n, j, m] = v
                j += 1
