"""The view evaluator: what the camera would see from candidate robot states, simulated by
ray casting in the occupancy map (numba kernels), and the view-dependent factors of the
utility: the information term (Vasquez-Gomez et al. 2017's surface factor, the ORT paper's
FIG/SIG/VUV/RSV, or Santos et al. 2020's score), the registration overlap (reg, Vasquez-Gomez et
al. 2017 eq. 5) and the director-ray test of candidate generation (§7.6 step 1)."""

from __future__ import annotations

import numpy as np

from ..config import Scenario, resolve_sensor
from ..mapping import view_metrics as K
from ..mapping.occupancy import OccupancyMap
from ..mapping.voxel import UNKNOWN, classes_grid
from ..world.robot import RobotKinematics
from ..world.sensor import ray_directions


class ViewEvaluator:
    """Scores robot states by simulating their scans in the map (batch numba kernel) with the
    sensor's model (mapping.view_metrics): the camera's pixel grid (one ray per
    planner.evaluator.stride x ray_stride block), field of view and depth range; each ray starts at
    the camera, and known surface within the minimum range blinds it. The planner's working
    range (planner.max_view_distance) is a separate filter of the candidates
    (candidates.StateSampler). near_unknown_blinds True: unknown space within the minimum
    range blinds a ray too (the conservative rule; see view_metrics for why it is not the
    default). Each evaluation estimates from the map the chance that an unknown voxel holds
    surface (`surface_probability`), for the expected returns on new surface."""

    def __init__(self, kin: RobotKinematics, sc: Scenario, stride: int | None = None, hrt_a: int | None = None,
                 near_unknown_blinds: bool = False):
        self.kin = kin
        self.near_unknown_blinds = bool(near_unknown_blinds)
        self.sensor = sc.sensor
        #: pixels per ray (side): `stride` as given, else planner.evaluator.stride model pixels
        #: of sensor.model_binning pixels each
        rs = resolve_sensor(sc.sensor)
        self.stride = stride or sc.planner.evaluator.stride * rs.model_binning
        self.hrt_a = sc.planner.hrt_a() if hrt_a is None else hrt_a
        self.dirs, self.t_near, self.t_far = ray_directions(sc.sensor, self.stride)
        #: planner.coarse_stride(): the first pass's rays of evaluate_ranked (None: off), in
        #: blocks of sensor.coarse_binning pixels
        coarse = sc.planner.coarse_stride() * rs.coarse_binning
        self.coarse_stride = coarse if coarse > self.stride else 0
        self.refine_views = sc.planner.refine_views(rs.refine_multiple)
        self.coarse = ray_directions(sc.sensor, self.coarse_stride) if self.coarse_stride else None
        #: the coarse pass's second look (sensor.recheck_binning; None: none): its rays, at
        #: coarse_stride blocks of that many pixels, for the views whose coarse rays came near
        #: known surface without one landing on it (`evaluate_ranked`)
        self.recheck_stride = sc.planner.coarse_stride() * rs.recheck_binning
        self.recheck = ray_directions(sc.sensor, self.recheck_stride) if (
            self.coarse is not None and self.stride < self.recheck_stride < self.coarse_stride) else None
        full, _, t_far = ray_directions(sc.sensor, 1)  # the outermost pixel centres bound every stride's rays
        self.frustum = (K.frustum_planes(full), float(t_far.max()))
        from ..world.sensor import intrinsics
        self.pitch = 1.0 / intrinsics(sc.sensor)[2]  # rad per pixel at the image centre
        #: the coverage radius r of the "coverage" information term (0: not computed)
        self.coverage_radius = sc.planner.coverage.radius if sc.planner.metric == "coverage" else 0.0
        import numba
        self.n_chunks = max(1, numba.get_num_threads())
        #: planner.view_occluders(): the known environment's boxes that end the views' rays
        self.occluders = K.known_occluders(sc.scene) if sc.planner.view_occluders() else None

    def evaluate(self, omap: OccupancyMap, q: np.ndarray) -> np.ndarray:
        """Metrics (N, K.N_METRICS) of the states q (N, 8); see view_metrics.M_*."""
        q = np.atleast_2d(q)
        if len(q) == 0:
            return np.zeros((0, K.N_METRICS))
        X = self.kin.camera_poses(q)
        return self.evaluate_poses(omap, X)

    def near_range_unknown(self, omap: OccupancyMap, q: np.ndarray) -> int:
        """The distinct unknown voxels that the rays of the view at state q (8,) cross within
        the sensor's minimum range, before any occupied voxel: the evaluator does not count
        them (view_metrics' sensor model), but a ray that returns clears them. Sampled every
        quarter voxel along the coarse pass's rays (the evaluator's own without one, dense
        enough for voxels this near the camera); a ray whose minimum range ends in an occupied voxel is
        blind and clears nothing. What a plan predicts it will reveal adds them
        (`perception.evaluation.plan_prediction`); a voxel that other rays also cross beyond
        the minimum range counts in both."""
        from ..mapping.voxel import OCCUPIED, UNKNOWN
        dirs, t_near = (self.coarse[0], self.coarse[1]) if self.coarse is not None else (self.dirs, self.t_near)
        t_near = np.asarray(t_near, float)
        if len(t_near) == 0 or t_near.max() <= 0.0:
            return 0
        X = self.kin.camera_poses(np.asarray(q, float)[None])[0]
        spec = omap.spec
        cls_grid = omap.classes()
        step = spec.res / 4.0
        t = np.arange(step / 2, t_near.max(), step)  # (S,)
        d = dirs @ X[:3, :3].T  # (R, 3) in the world
        seen = []
        for a in range(0, len(d), 1000):  # rays in chunks: (1000, S, 3) points at a time
            p = X[:3, 3] + t[None, :, None] * d[a:a + 1000, None, :]
            idx = np.floor((p - spec.bmin) / spec.res).astype(np.int64)
            inside = np.all((idx >= 0) & (idx < np.array(spec.dims)), axis=-1) & (t[None] < t_near[a:a + 1000, None])
            cls = np.full(inside.shape, -1, np.int64)
            cls[inside] = cls_grid[idx[inside][:, 0], idx[inside][:, 1], idx[inside][:, 2]]
            take = (cls == UNKNOWN) & ~(cls == OCCUPIED).any(axis=1)[:, None]
            seen.append(np.ravel_multi_index(idx[take].T, spec.dims))
        return int(len(np.unique(np.concatenate(seen))))

    def evaluate_coarse(self, omap: OccupancyMap, q: np.ndarray) -> np.ndarray:
        """Metrics (N, K.N_METRICS) of the states q (N, 8) from the coarse pass's rays
        (planner.evaluator.coarse_stride), the per-ray columns on the scale of this evaluator's
        ray count (`coarse_to_exact_scale`); without a coarse pass, `evaluate`."""
        q = np.atleast_2d(q)
        if self.coarse is None or len(q) == 0:
            return self.evaluate(omap, q)
        return self._coarse_poses(omap, self.kin.camera_poses(q))

    def _coarse_poses(self, omap: OccupancyMap, X: np.ndarray, **kw) -> np.ndarray:
        """Metrics of camera poses X from the coarse pass's rays (`evaluate_poses` keywords),
        the per-ray columns on the scale of this evaluator's ray count."""
        met = self.evaluate_poses(omap, X, rays=self.coarse, **kw)
        return coarse_to_exact_scale(met, len(self.coarse[0]), len(self.dirs))

    def evaluate_ranked(self, omap: OccupancyMap, q: np.ndarray, score) -> tuple[np.ndarray, np.ndarray]:
        """(metrics (N, K.N_METRICS), order): the states' metrics and their ranking by
        `score(metrics (N, K.N_METRICS))` (N,), best first (stable; `score` may carry
        `surface_margin` and `per_ray`, see ranking_score). With planner.coarse_stride(), coarse to fine:
        every state is evaluated with the coarse rays first (the per-ray columns scaled to this
        evaluator's ray count, PER_RAY_COLUMNS), the best `refine_views` of that ranking again
        at ray_stride; the order lists those by their exact score, then the others by their
        coarse one. Without, every state at ray_stride (the exact ranking).
        With a second look (sensor.recheck_binning), the views whose coarse rays came near known
        surface without one landing on it (no M_OC_RAYS, but `score.info` above 0: the
        registration filter undecided, a sliver of surface between the coarse rays) are
        evaluated again with the second look's denser rays before the ranking."""
        q = np.atleast_2d(q)
        if self.coarse is None or len(q) <= self.refine_views:
            met = self.evaluate(omap, q)
            return met, np.argsort(-score(met), kind="stable")
        X = self.kin.camera_poses(q)
        met = np.zeros((len(q), K.N_METRICS))
        seen = self.may_score(omap, X, getattr(score, "surface_margin", None))
        kw = dict(score_only=getattr(score, "per_ray", False), roi_margin=getattr(score, "roi_margin", None))
        met[seen] = self._coarse_poses(omap, X[seen], **kw)
        info = getattr(score, "info", None)
        if self.recheck is not None and info is not None:
            again = seen & (met[:, K.M_OC_RAYS] == 0) & (info(met) > 0)
            if again.any():
                met[again] = coarse_to_exact_scale(
                    self.evaluate_poses(omap, X[again], rays=self.recheck, stride=self.recheck_stride, **kw),
                    len(self.recheck[0]), len(self.dirs))
        head = np.argsort(-score(met), kind="stable")[:self.refine_views]
        head = head[seen[head]]
        met[head] = self.evaluate_poses(omap, X[head])
        g = score(met)
        head = head[np.argsort(-g[head], kind="stable")]
        tail = np.setdiff1d(np.arange(len(q)), head)
        tail = tail[np.argsort(-g[tail], kind="stable")]
        return met, np.concatenate([head, tail])

    def may_score(self, omap: OccupancyMap, X: np.ndarray, margin: float | None) -> np.ndarray:
        """Which camera poses X (N, 4, 4) may score above 0 under a ranking whose views score 0
        unless their rays reach known surface within `margin` voxels (ranking_score's
        surface_margin): the frustum culling of the coarse-to-fine evaluation, exact for that
        ranking (view_metrics.views_see_spheres is conservative). None: every pose."""
        if margin is None or len(X) == 0:
            return np.ones(len(X), bool)
        centres = self._per_map("occupied_centres", omap.logodds, lambda: K.occupied_centres(
            omap.classes(), omap.spec.bmin.astype(np.float64), omap.spec.res))
        if len(centres) == 0:
            return np.zeros(len(X), bool)
        radius = (np.sqrt(3.0) / 2.0 + margin) * omap.spec.res
        planes, t_far = self.frustum
        return K.views_see_spheres(centres, radius, np.ascontiguousarray(X[:, :3, 3]),
                                   np.ascontiguousarray(X[:, :3, :3]), planes, t_far)

    def voxel_sorting_score(self, omap: OccupancyMap, q: np.ndarray, w: float = 0.5) -> np.ndarray:
        """Santos et al. 2020's score of states q (voxel-sorted ray casting), within the sensor's range."""
        from ..mapping import voxel_sorting
        from ..world.sensor import intrinsics
        q = np.atleast_2d(q)
        if len(q) == 0:
            return np.zeros(0)
        X = self.kin.camera_poses(q)
        m = omap.model
        cls = classes_grid(np.ascontiguousarray(omap.logodds, dtype=np.float32), m.l_free, m.l_occ)
        wd, ht, fx, fy, cx, cy = intrinsics(self.sensor)
        s = resolve_sensor(self.sensor)
        res = voxel_sorting.voxel_sorted_views(cls, omap.spec.bmin.astype(np.float64), omap.spec.res,
                                         np.ascontiguousarray(X[:, :3, 3]), np.ascontiguousarray(X[:, :3, :3]),
                                         fx, fy, cx, cy, wd, ht, s.z_near, s.z_far, min(self.n_chunks, len(q)),
                                         self.near_unknown_blinds)
        outer, inner = voxel_sorting.unknown_volumes(cls == UNKNOWN, omap.spec.res)
        return voxel_sorting.score(res[:, 0], res[:, 1], omap.spec.res, outer, inner, w)

    def information(self, omap: OccupancyMap, q: np.ndarray, met: np.ndarray, metric: str, un_total: int):
        """The information term of states q whose ray metrics are `met`."""
        if metric == "seed001":
            return self.voxel_sorting_score(omap, q)
        return information(met, metric, un_total, len(self.dirs), omap.spec.res)

    #: the coverage gain expects new surface only next to known surface (near_surface); False:
    #: in every unknown voxel alike, the first model (kept for diagnostics.candidate_gains)
    near_surface_model = True

    def _per_map(self, name: str, src: np.ndarray, compute):
        """compute(), once per `src` array of a map (a map's arrays are read-only, replaced, not
        changed, by each scan): the expected utility evaluates the rollouts of every candidate
        against the same map."""
        memo = self.__dict__.setdefault("_memo", {})
        have = memo.get(name)
        if have is None or have[0] is not src:
            have = memo[name] = (src, compute())
        return have[1]

    def _density(self, omap: OccupancyMap) -> np.ndarray:
        """sample_density(omap), once per set of object points."""
        thin = resolve_sensor(self.sensor).model_binning ** 2
        return self._per_map("density", omap.object_points, lambda: sample_density(omap, thin=thin))

    def _near(self, omap: OccupancyMap):
        """near_surface(omap), once per occupancy grid."""
        return self._per_map("near", omap.logodds, lambda: near_surface(omap))

    def evaluate_poses(self, omap: OccupancyMap, X: np.ndarray, rays=None, score_only: bool = False,
                       roi_margin: float | None = None, stride: int | None = None) -> np.ndarray:
        """Metrics of camera poses X (N, 4, 4); `rays`: (dirs, t_near, t_far) of another
        stride than ray_stride (the coarse pass; `stride` its pixels per ray, None: coarse_stride),
        whose M_COVER_GAIN weights each ray by its own stride; `score_only`: the per-ray columns
        only (view_metrics.evaluate_views)."""
        pos = np.ascontiguousarray(X[:, :3, 3])
        rot = np.ascontiguousarray(X[:, :3, :3])
        m = omap.model
        lo = np.ascontiguousarray(omap.logodds, dtype=np.float32)
        dirs, t_near, t_far = (self.dirs, self.t_near, self.t_far) if rays is None else rays
        if stride is None:
            stride = self.stride if rays is None else self.coarse_stride
        args = (omap.spec.bmin.astype(np.float64), omap.spec.res, pos, rot, dirs, t_near,
                t_far, m.l_free, m.l_occ, min(self.n_chunks, len(pos)))
        kw = dict(near_unknown_blinds=self.near_unknown_blinds, surface_q=surface_probability(omap))
        if score_only:
            kw.update(score_only=True, roi_margin=-1.0 if roi_margin is None else float(roi_margin))
        if self.hrt_a > 0:
            return K.evaluate_views_hrt(lo, self.hrt_a, *args, **kw)
        if self.occluders is not None:
            kw.update(occluders=self.occluders)
        if self.coverage_radius > 0:
            kw.update(density=self._density(omap), cov_k=np.pi * self.coverage_radius ** 2, pitch=self.pitch,
                      stride=stride)
            if self.near_surface_model:
                near, near_q = self._near(omap)
                kw.update(near=near, near_q=near_q)
        return K.evaluate_views(lo, *args, **kw)


def ranking_score(evaluator: ViewEvaluator, omap: OccupancyMap, metric: str, overlap_h: float | None,
                  un_total: int):
    """score(metrics) -> (N,): the ranking of random sampling (Vasquez-Gomez et al. 2017 §7.6
    steps 4-6): the information term of the views that pass the registration filter
    (overlap > h; None: no filter), 0 for the others."""
    def info(met):
        return evaluator.information(omap, None, met, metric, un_total)

    def score(met):
        i = info(met)
        return i if overlap_h is None else np.where(registration_overlap(met) > overlap_h, i, 0.0)
    # the information term before the registration filter (the coarse pass's second look)
    score.info = info
    # whether the score reads the per-ray columns only (the coarse pass may skip the distinct
    # voxel sets: view_metrics.evaluate_views' score_only)
    score.per_ray = metric in ("coverage", "surface", "sig", "rsv")
    # the coarse pass may trace only the rays towards known surface (grown by this many
    # voxels): the coverage gain of such rays alone, and the registration filter when h = 0
    # (overlap > 0 needs one ray on known surface, whatever the others do)
    score.roi_margin = NEAR_SURFACE_VOXELS if (
        metric == "coverage" and evaluator.near_surface_model and overlap_h in (None, 0.0)) else None
    # how near known surface a view's rays must come for it to score above 0 (voxels): the
    # registration filter needs rays on known surface (overlap > h >= 0 needs oc_rays > 0);
    # without it the coverage gain needs known surface or the unknown voxels near it
    # (near_surface); the other terms score any unknown space (no culling)
    if overlap_h is not None:
        score.surface_margin = 0.0
    elif metric == "coverage" and evaluator.near_surface_model:
        score.surface_margin = NEAR_SURFACE_VOXELS
    else:
        score.surface_margin = None
    return score


def scaled_score(score, factor: np.ndarray):
    """A ranking_score times a per-view factor (the ORT's distance factor), keeping its
    surface_margin (a factor does not make a view score that scores 0), per_ray and
    roi_margin (the factor is the same for all of a view's rays)."""
    def scaled(met):
        return score(met) * factor
    scaled.surface_margin = score.surface_margin
    scaled.per_ray = score.per_ray
    scaled.roi_margin = score.roi_margin
    scaled.info = score.info
    return scaled


#: the metrics that count rays (scaled by the ray counts between strides); the distinct-voxel
#: columns (VUV, oc_o, FIG, n_posterior) are not: with rays closer than a voxel's footprint
#: (SR4000 at stride 8: 3.6 cm at 1 m against 2 cm voxels, nearly so) both strides touch
#: about the same voxels; M_COVER_GAIN weights each ray by its pixel area already
PER_RAY_COLUMNS = [K.M_SIG, K.M_RSV, K.M_RAYS, K.M_OC_RAYS, K.M_UN_RAYS, K.M_BLIND_RAYS, K.M_NEW_RAYS,
                   K.M_NEW_EXPECTED]


def coarse_to_exact_scale(met: np.ndarray, n_coarse: int, n_exact: int) -> np.ndarray:
    """Metrics of a coarse pass (n_coarse rays per view) on the scale of n_exact rays."""
    met = met.copy()
    met[:, PER_RAY_COLUMNS] *= n_exact / max(n_coarse, 1)
    return met


#: neighbours of each model point whose distance gives its local sample density
DENSITY_NEIGHBOURS = 10


def sample_density(omap: OccupancyMap, k: int = DENSITY_NEIGHBOURS, thin: int = 1) -> np.ndarray:
    """Samples per m^2 of surface in each voxel (float32 grid; 0 where the map has no object
    point): the median over the voxel's object points of their local density (k - 1/3) /
    (pi d_k^2), d_k the distance to a point's k-th nearest neighbour among the map's points
    (for samples spread at random over a surface at density D, pi d_k^2 D is Gamma(k, 1)
    distributed, whose median is about k - 1/3: the voxel's median is then about D).

    The points in a voxel over the voxel's face area, the first estimate, saw a surface that
    only clips a voxel's corner as sparsely sampled however dense its samples were: on the
    bunny after 12 scans it put the surface not yet covered at 3 mm within the observed
    voxels at 0.051 m^2 where the ground truth left 0.015 m^2 (this estimate: 0.019 m^2), and
    the planner kept returning to surface it had covered (docs/decisions.md).

    `thin` > 1 (sensor.model_binning^2: the Kinect's 3 x 3 pixels): the voxel's median over
    every thin-th of its points (their neighbours still among all points), and over all the
    points of a voxel none of those falls in: a Kinect scan adds tens of thousands of points,
    and the neighbour queries of every point took 6 s of a chair plan by the 19th scan."""
    from scipy.spatial import cKDTree
    dims = omap.spec.dims
    out = np.zeros(dims, np.float32)
    pts = np.asarray(omap.object_points, np.float64)
    idx, inside = omap.spec.voxel_index(pts)
    if int(np.count_nonzero(inside)) == 0 or len(pts) <= k * thin:
        return out
    if thin == 1:
        dk = cKDTree(pts).query(pts[inside], k + 1)[0][:, -1]  # the nearest is the point itself
        vox, med = _median_by(np.ravel_multi_index(idx[inside].T, dims), _knn_density(k, dk))
    else:
        key = np.ravel_multi_index(np.where(inside[:, None], idx, 0).T, dims)
        ask = np.zeros(len(pts), bool)
        ask[::thin] = True
        ask &= inside
        ask |= inside & ~np.isin(key, key[ask])  # the points of voxels no asked point falls in
        dk = cKDTree(pts).query(pts[ask], k + 1)[0][:, -1]
        vox, med = _median_by(key[ask], _knn_density(k, dk))
    out.reshape(-1)[vox] = med
    return out


def _knn_density(k, dk: np.ndarray) -> np.ndarray:
    """Samples per m^2 at a point whose k-th neighbour (k may be per point) lies at dk:
    (k - 1/3) / (pi dk^2) (see sample_density)."""
    return (k - 1.0 / 3.0) / (np.pi * np.maximum(dk, 1e-6) ** 2)


def _median_by(key: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distinct keys, the median of each key's values): the upper middle for an even count."""
    order = np.lexsort((values, key))  # by key, then by value
    keys, start, count = np.unique(key[order], return_index=True, return_counts=True)
    return keys, values[order][start + count // 2]


#: unknown voxels within this many voxels of known surface may hold new surface (the
#: coverage gain's model of the unknown space; see near_surface)
NEAR_SURFACE_VOXELS = 4.0


def near_surface(omap: OccupancyMap, reach: float = NEAR_SURFACE_VOXELS) -> tuple[np.ndarray, float]:
    """Where the coverage gain expects new surface: the unknown voxels within `reach` voxels
    (Euclidean) of an occupied one (bool grid), and the chance q_near that such a voxel holds
    surface, estimated as the occupied share of the known voxels of W_box within the same reach
    of occupied ones.

    The object is one connected surface, so what the scans have not seen of it continues
    from what they have: a ray that reaches known surface through unknown voxels next to it
    comes from behind that surface and returns on new surface; unknown voxels far from every
    known surface are the air outside the first views' frustums and beyond the object in
    their shadows. Treating all unknown space alike (q = occupied / known voxels of W_box),
    the first model, predicted 0.22 m^2 of new surface for a second view of the bunny beside
    the first where the scan gave 0.02 m^2, and ranked views of the far side no higher:
    over 120 candidates rendered after the first scan, the rank correlation of predicted and
    measured coverage gain was 0.59 (bunny) and 0.34 (teapot); with this model 0.96 and 0.97,
    and the view predicted best added 0.317 and 0.266 of the ground truth where the best of
    the 120 added 0.317 and 0.268 (docs/decisions.md; `nbvs bench prediction` measures it)."""
    from scipy import ndimage

    from ..mapping.voxel import FREE, OCCUPIED
    c = omap.classes()
    occ = c == OCCUPIED
    if not occ.any():
        return np.zeros(c.shape, bool), 0.0
    # the distance transform on the occupied voxels' bounding box grown by the reach (all a
    # voxel within reach can be): the same grid, a fraction of the voxels on a fine map
    pad = int(np.ceil(reach)) + 1
    nz = np.nonzero(occ)
    box = tuple(slice(max(int(i.min()) - pad, 0), min(int(i.max()) + pad + 1, n)) for i, n in zip(nz, occ.shape))
    close = np.zeros(c.shape, bool)
    sub = ~occ[box]
    # voxels outside the box lie farther than `reach` from every occupied voxel; inside it the
    # nearest occupied voxel of a voxel within reach is inside it too
    close[box] = ndimage.distance_transform_edt(sub) <= reach
    near = close & (c == UNKNOWN)
    sel = c[close & omap.in_wbox()]
    n_occ, n_free = int(np.count_nonzero(sel == OCCUPIED)), int(np.count_nonzero(sel == FREE))
    return np.ascontiguousarray(near), (n_occ / (n_occ + n_free) if n_occ + n_free else 0.0)


def surface_probability(omap: OccupancyMap) -> float:
    """The chance that an unknown voxel of W_box holds surface, estimated from what the scans
    have seen of W_box: occupied / (occupied + free) voxels there (0 before any scan). The
    expected returns on new surface (view_metrics.M_NEW_EXPECTED) weight a ray that crosses n
    unknown voxels and meets nothing by 1 - (1 - q)^n."""
    from ..mapping.voxel import FREE, OCCUPIED
    c = omap.classes()[omap.in_wbox()]
    occ, free = int(np.count_nonzero(c == OCCUPIED)), int(np.count_nonzero(c == FREE))
    return occ / (occ + free) if occ + free else 0.0


def registration_overlap(met: np.ndarray) -> np.ndarray:
    """Share of the simulated scan's expected returns that land on known surface: rays whose
    first non-free voxel is occupied (oc_rays) against those plus the rays expected to return
    on new surface (view_metrics.M_NEW_EXPECTED). reg(x) = 1 when this exceeds h
    (Vasquez-Gomez et al. 2017 eq. 5, measured per ray: ICP needs overlapping points, and
    distinct-voxel counts let the large side faces of the occlusion shadow behind a first scan
    veto every nearby view). A ray through unknown space that is most likely air (it meets no
    surface) returns on the known table or nothing, so it does not count against the overlap:
    counting every ray whose first non-free voxel is unknown, the old rule, predicted 0.3-0.4
    where the scans then measured 0.9-0.99 (evaluation.scan_outcome)."""
    oc, new = met[:, K.M_OC_RAYS], met[:, K.M_NEW_EXPECTED]
    tot = oc + new
    return np.where(tot > 0, oc / np.maximum(tot, 1e-12), 0.0)


def information(met: np.ndarray, metric: str, un_total: int, n_rays: int = 1,
                res: float | None = None) -> np.ndarray:
    """The information term I(x) of the utility, normalised by the unknown voxels (entropy
    metrics also by ln 2, a voxel's maximum entropy): sur = VUV = un_o (Vasquez-Gomez et al.
    2017 eq. 6), fig, sig, rsv (the ORT paper); "surface": the share of the view's `n_rays`
    rays expected to return on new surface (view_metrics.M_NEW_EXPECTED); "coverage": the
    covered area gained (view_metrics.M_COVER_GAIN) over un_total voxel faces of size `res`. seed001: see
    ViewEvaluator.voxel_sorting_score."""
    if metric == "surface":
        return met[:, K.M_NEW_EXPECTED] / max(n_rays, 1)
    if metric == "coverage":  # covered area gained, in units of the unknown voxels' faces (res: voxel size)
        if res is None:
            raise ValueError("information: metric coverage needs the map's voxel size res")
        return met[:, K.M_COVER_GAIN] / max(un_total * res ** 2, 1e-12)
    col = {"sur": K.M_UN_O, "vuv": K.M_VUV, "fig": K.M_FIG, "sig": K.M_SIG, "rsv": K.M_RSV}[metric]
    norm = un_total * (np.log(2.0) if metric in ("fig", "sig") else 1.0)
    return met[:, col] / max(norm, 1e-12)


def director_ray_hits(X: np.ndarray, bmin, bmax, t_near: float, t_far: float) -> np.ndarray:
    """Whether each camera's optical axis meets the box within [t_near, t_far] (it enters
    the box before t_far and leaves it after t_near)."""
    o = X[:, :3, 3]
    d = X[:, :3, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        ta = (np.asarray(bmin) - o) * inv
        tb = (np.asarray(bmax) - o) * inv
    t0 = np.nanmax(np.minimum(ta, tb), axis=1)
    t1 = np.nanmin(np.maximum(ta, tb), axis=1)
    return (t0 <= t1) & (t1 >= t_near) & (t0 <= t_far)
