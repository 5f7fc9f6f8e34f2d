"""The flat schema of 79445c7 and before (one `planner` and one `mission` section of flags),
and the migration from it: a record's or a user's old `scenario.yaml`, and an old dotted
setting (`--set planner.hrt_a=2`), load through `migrate` into today's nested schema with the
same meaning. Options removed since (they were used by no scenario, preset or experiment)
are refused when set to anything but their old default."""


import dataclasses as dc

from ..errors import ScenarioError
from . import schema as S

_REG = S.REGISTERED_SIGMA

# ---- the old schema, as it was (values only; the meanings are in schema.py) ----

@dc.dataclass
class OldRobotConfig:
    urdf: str = "patrolbot_katana.urdf"  #: relative to models/ (or absolute)
    start: list[float] = dc.field(
        default_factory=lambda: [-1.45, 0.0, 0.0, 0.0, 0.35, -0.35, -0.25, 0.0])
    xy_bounds: list[float] = dc.field(default_factory=lambda: [-1.9, 1.9])
    control_dt: float = 0.1  #: each control u_t is held for this long (s)
    max_linear_velocity: float = 0.3  #: m/s used by the steering function
    max_angular_velocity: float = 0.6  #: rad/s (base)
    max_arm_velocity: float = 0.6  #: rad/s (each arm joint, below the Katana limits)


@dc.dataclass
class OldObjectConfig:
    """The object: mesh -> `up` -> `rpy_deg` -> `yaw_deg`, scaled, then set on the table
    (lowest point on the table top, footprint centred at `xy`)."""
    kind: str = "teapot"
    mesh: str = ""  #: OBJ/PLY/STL/OFF/glTF/GLB path (relative to the scenario file) when kind = mesh
    size: float = -1.0
    scale: float = 1.0  #: mesh units -> metres, used when size = 0
    xy: list[float] = dc.field(default_factory=lambda: [0.0, 0.0])  #: footprint centre on the table
    up: str = ""
    rpy_deg: list[float] = dc.field(default_factory=lambda: [0.0, 0.0, 0.0])
    yaw_deg: float = 0.0  #: then a turn about the vertical, degrees
    tessellation: int = 12  #: teapot: subdivisions per Bezier patch side




@dc.dataclass
class OldSceneConfig:
    table_size: list[float] = dc.field(default_factory=lambda: [0.8, 1.0])  #: x, y (m)
    table_height: float = 0.43  #: top surface z (m)
    bbox_min: list[float] = dc.field(default_factory=lambda: [-0.4, -0.4, 0.43])  #: W_box
    bbox_max: list[float] = dc.field(default_factory=lambda: [0.4, 0.4, 0.95])
    clutter: str = "none"  #: "none" or "chairs" (nine chairs around the table, Vasquez-Gomez et al. 2017 Fig. 13)
    object: OldObjectConfig = dc.field(default_factory=OldObjectConfig)
    gt_points: int = 40000  #: ground-truth surface samples for coverage


@dc.dataclass
class OldSensorConfig:
    preset: str = "sr4000"
    width: int = 0  #: 0: from the preset
    height: int = 0
    fov_x_deg: float = 0.0
    fov_y_deg: float = 0.0
    z_near: float = 0.0
    z_far: float = 0.0
    noise_a: float = -1.0
    noise_b: float = -1.0




@dc.dataclass
class OldNoiseConfig:
    """Zero-mean Gaussian control noise (Vasquez-Gomez et al. 2017 §6.1), truncated at +-beta sigma."""
    sigma_v: float = 0.00165  #: m/s (Table 4: 1.65 mm/s)
    sigma_w: float = 0.28  #: rad/s (Table 4)
    sigma_arm: list[float] = dc.field(default_factory=lambda: [0.0] * 5)  #: rad/s
    beta: float = 3.0  #: truncation in units of sigma
    perturb_zero_commands: bool = False


@dc.dataclass
class OldMapperConfig:
    voxel_size: float = 0.02
    margin: float = 0.04  #: map = W_box grown by this (x, y, top); the table bounds it below
    prob_hit: float = 0.7  #: OctoMap sensor model
    prob_miss: float = 0.4
    clamp_min: float = 0.1192
    clamp_max: float = 0.971
    free_below: float = 0.45  #: class thresholds: free < 0.45 <= unknown <= 0.55 < occupied
    occupied_above: float = 0.55
    table_clearance: float = 0.005




@dc.dataclass
class OldPlannerConfig:
    strategy: str = "random_sampling"
    view_poses: int = 60  #: view_sampling: poses per iteration, spread over the clusters
    circle_views: int = 12
    circle_range: float = 0.0
    circle_height: float = 0.0
    metric: str = "sur"
    coverage_radius: float = 0.003
    ort_vertices: int = 10000  #: ORT tree size k (the ORT paper: 10^4 is the good trade-off)
    ort_batch: int = 64
    tree_step: float = 1.0  #: tree extension step in the weighted metric of eq. 8
    rrt_max_nodes: int = 10000
    motion_planner: str = "rrt_ext_ext"
    roadmap_vertices: int = 1500
    roadmap_neighbors: int = 10  #: roadmap: edges to this many nearest vertices (eq. 8 metric)
    detour_steering: bool = False
    arc_steering: bool = False
    free_goal_heading: bool = False
    n_candidates: int = 4000  #: state samples whose director ray meets W_box
    overlap_h: float = 0.5  #: registration threshold h (Table 1: 50 %)
    top_k: int = 25  #: candidates kept for motion planning (§7.6 step 7)
    weights: list[float] = dc.field(
        default_factory=lambda: [10.0, 10.0, 0.5, 0.05, 0.05, 0.05, 0.05, 0.05])
    use_distance: bool = True
    utility: str = "du"
    eu_samples: int = 500  #: k rollouts per candidate (Table 7: 500)
    eu_weighting: str = "probability"
    eu_max_collision_rate: float = 0.0
    eu_rollout_registration: bool = True
    eu_free_start: bool = False
    noise_fallback: bool = False
    eu_registered_sigma: list[float] = dc.field(default_factory=lambda: list(_REG))
    eu_alpha: float = 0.01  #: eq. 18: warn when k < log(alpha) / log(1 - eta gamma)
    eu_gamma: float = 0.05
    map_obstacles: str = "wbox"
    max_obstacle_boxes: int = 300
    ray_stride: int = 2  #: evaluate every n-th pixel row/column when scoring views
    coarse_stride: int = 0
    refine_views: int = 0
    view_occluders: bool = False
    facing_density: bool = False
    base_clearance: float = 0.0
    hrt_a: int = 0
    max_view_distance: float = 1.0
    max_generation_factor: int = 200  #: at most this many x n_candidates raw samples


@dc.dataclass
class OldMissionConfig:
    max_scans: int = 12
    max_sim_time: float = 7200.0  #: simulated seconds before the run is cut off
    relocalization: str = "icp"
    skip_unregistered_scans: bool = True
    on_collision: str = "stop"
    coverage_ceiling: bool = True
    verify_views: bool = False
    legs: bool = False
    leg_turns: bool = False
    recovery_rollouts: int = 0
    refine_scan_registration: bool = False
    view_tolerance_m: float = 0.03
    view_tolerance_rad: float = 0.05
    max_recoveries: int = 3
    landmark_occlusion: bool = False
    landmark_facing: bool = False
    registration_residual_cap: float = -1.0
    fine_registration: bool = False
    merge_frames: bool = True
    stop_unknown_voxels: int = 0
    stop_min_surface: float = 0.0
    stop_min_utility: float = 0.0



@dc.dataclass
class OldScenario:
    name: str = "default"
    seed: int = 0
    robot: OldRobotConfig = dc.field(default_factory=OldRobotConfig)
    scene: OldSceneConfig = dc.field(default_factory=OldSceneConfig)
    sensor: OldSensorConfig = dc.field(default_factory=OldSensorConfig)
    noise: OldNoiseConfig = dc.field(default_factory=OldNoiseConfig)
    mapper: OldMapperConfig = dc.field(default_factory=OldMapperConfig)
    planner: OldPlannerConfig = dc.field(default_factory=OldPlannerConfig)
    mission: OldMissionConfig = dc.field(default_factory=OldMissionConfig)
    base_dir: str = ""



# ---- the migration ----

#: options removed, with the old default they must have (anything else is refused)
REMOVED = {("noise", "perturb_zero_commands"): False, ("mission", "merge_frames"): True,
           ("planner", "eu_rollout_registration"): True, ("planner", "facing_density"): False}

#: keys that exist only in the old schema: a scenario holding one of them is an old one
_OLD_ONLY = {
    "planner": {"view_poses", "circle_views", "circle_range", "circle_height", "coverage_radius", "ort_vertices",
                "ort_batch", "rrt_max_nodes", "roadmap_vertices", "roadmap_neighbors", "detour_steering",
                "arc_steering", "free_goal_heading", "eu_samples", "eu_weighting", "eu_max_collision_rate",
                "eu_rollout_registration", "eu_free_start", "eu_registered_sigma", "eu_alpha", "eu_gamma",
                "map_obstacles", "max_obstacle_boxes", "ray_stride", "coarse_stride", "refine_views",
                "view_occluders", "facing_density", "base_clearance", "hrt_a"},
    "mission": {"relocalization", "skip_unregistered_scans", "verify_views", "legs", "leg_turns",
                "recovery_rollouts", "refine_scan_registration", "view_tolerance_m", "view_tolerance_rad",
                "max_recoveries", "landmark_occlusion", "landmark_facing", "registration_residual_cap",
                "fine_registration", "merge_frames"},
    "noise": {"perturb_zero_commands"},
}
#: old planner keys whose value was a word where today's is a tagged mapping
_OLD_WORDS = {"strategy", "utility", "motion_planner"}


def is_old_document(doc) -> bool:
    """Whether a parsed scenario YAML mapping is written in the old flat schema."""
    if not isinstance(doc, dict):
        return False
    for sec, keys in _OLD_ONLY.items():
        d = doc.get(sec)
        if isinstance(d, dict) and keys & set(d):
            return True
    p = doc.get("planner")
    return isinstance(p, dict) and any(isinstance(p.get(k), str) for k in _OLD_WORDS)


#: fields of both schemas whose old magic values mean what today's None does
_OLD_MAGIC = {"scene.object.size": ("-1", "-1.0", "0", "0.0"), "scene.object.up": ('""', "''"),
              "scene.object.mesh": ('""', "''"), "planner.max_view_distance": ("0", "0.0"),
              **{f"sensor.{k}": ("0", "0.0") for k in ("width", "height", "fov_x_deg", "fov_y_deg", "z_near", "z_far")},
              **{f"sensor.{k}": ("-1", "-1.0") for k in ("noise_a", "noise_b")}}


def is_old_setting(key: str, value: str = "") -> bool:
    """Whether a dotted setting ("planner.hrt_a", "scene.object.size=-1") is one of the old
    schema's."""
    if value.strip() in _OLD_MAGIC.get(key, ()):
        return True
    parts = key.split(".")
    if len(parts) == 2 and parts[1] in _OLD_ONLY.get(parts[0], ()):
        return True
    return (len(parts) == 2 and parts[0] == "planner" and parts[1] in _OLD_WORDS
            and not value.strip().startswith(("!", "{")))


def _copy(cls, old):
    """cls from the fields of `old` it shares (a field added since takes its default)."""
    return cls(**{f.name: getattr(old, f.name) for f in dc.fields(cls) if hasattr(old, f.name)})


def from_old(o: OldScenario) -> S.Scenario:
    """Today's scenario with the meaning of an old one."""
    for (sec, key), default in REMOVED.items():
        if getattr(getattr(o, sec), key) != default:
            raise ScenarioError(f"{sec}.{key} was removed (docs/decisions.md); "
                                f"only {str(default).lower()} is possible")
    oo, os_, p, m = o.scene.object, o.sensor, o.planner, o.mission
    obj = S.ObjectConfig(kind=oo.kind, mesh=oo.mesh or None,
                         size=oo.size if oo.size > 0 else None, scale=oo.scale if oo.size == 0 else None,
                         xy=list(oo.xy), up=oo.up or None, rpy_deg=list(oo.rpy_deg), yaw_deg=oo.yaw_deg,
                         tessellation=oo.tessellation)
    scene = S.SceneConfig(table_size=list(o.scene.table_size), table_height=o.scene.table_height,
                          bbox_min=list(o.scene.bbox_min), bbox_max=list(o.scene.bbox_max),
                          clutter=o.scene.clutter, object=obj, gt_points=o.scene.gt_points)
    sensor = S.SensorConfig(preset=os_.preset, **{
        k: (None if (getattr(os_, k) < 0 if k.startswith("noise") else getattr(os_, k) == 0) else getattr(os_, k))
        for k in ("width", "height", "fov_x_deg", "fov_y_deg", "z_near", "z_far", "noise_a", "noise_b")})
    if os_.preset == "kinect":  # the old Kinect had axial noise only, and a ray per pixel block of stride
        sensor.faults = S.DepthFaults.none()
        sensor.model_binning = 1
        sensor.coarse_binning = 1
        sensor.recheck_binning = 0
        sensor.refine_multiple = 1
    noise = S.NoiseConfig(sigma_v=o.noise.sigma_v, sigma_w=o.noise.sigma_w, sigma_arm=list(o.noise.sigma_arm),
                          beta=o.noise.beta)
    strategy = {"random_sampling": lambda: S.RandomSampling(),
                "ort": lambda: S.Ort(vertices=p.ort_vertices, batch=p.ort_batch),
                "view_sampling": lambda: S.ViewSampling(poses=p.view_poses),
                "view_circle": lambda: S.ViewCircle(views=p.circle_views, range=p.circle_range or None,
                                                    height=p.circle_height or None),
                "random_views": lambda: S.RandomViews(), "oracle": lambda: S.Oracle()}
    if p.strategy not in strategy:
        raise ScenarioError(f"planner.strategy must be one of {', '.join(strategy)}, got {p.strategy!r}")
    if p.hrt_a > 0:
        evaluator = S.Hrt(a=p.hrt_a, stride=p.ray_stride)
    else:
        evaluator = S.Exact(stride=p.ray_stride, coarse_stride=p.coarse_stride or None,
                            refine=p.refine_views or None, occluders=p.view_occluders)
    utility = (S.Expected(samples=p.eu_samples, weighting=p.eu_weighting, max_collision_rate=p.eu_max_collision_rate,
                          free_start=p.eu_free_start, alpha=p.eu_alpha, gamma=p.eu_gamma)
               if p.utility == "eu" else S.Deterministic())
    if p.utility not in ("du", "eu"):
        raise ScenarioError(f"planner.utility must be 'du' or 'eu', got {p.utility!r}")
    if p.motion_planner == "roadmap":
        motion = S.Roadmap(vertices=p.roadmap_vertices, neighbors=p.roadmap_neighbors,
                           free_goal_heading=p.free_goal_heading)
    elif p.motion_planner == "rrt_ext_ext":
        motion = S.RrtExtExt(max_nodes=p.rrt_max_nodes)
    else:
        raise ScenarioError(f"planner.motion_planner must be 'rrt_ext_ext' or 'roadmap', got {p.motion_planner!r}")
    mvd = p.max_view_distance
    if mvd == 0:  # old "0: the sensor's z_far"
        mvd = float(sensor.resolved().z_far)
    planner = S.PlannerConfig(
        strategy=strategy[p.strategy](), metric=p.metric,
        coverage=S.CoverageGain(radius=p.coverage_radius),
        n_candidates=p.n_candidates, max_generation_factor=p.max_generation_factor, max_view_distance=mvd,
        overlap_h=p.overlap_h, top_k=p.top_k, weights=list(p.weights), use_distance=p.use_distance,
        evaluator=evaluator, utility=utility, motion_planner=motion, tree_step=p.tree_step,
        steering=S.Steering(detours=p.detour_steering, arcs=p.arc_steering),
        obstacles=S.Obstacles(map=p.map_obstacles, max_boxes=p.max_obstacle_boxes, base_clearance=p.base_clearance),
        noise_fallback=p.noise_fallback)
    vv = None
    if m.verify_views:
        vv = S.VerifiedViews(tolerance_m=m.view_tolerance_m, tolerance_rad=m.view_tolerance_rad,
                             max_recoveries=m.max_recoveries,
                             legs=S.Legs(after_turns=m.leg_turns) if m.legs else None,
                             recovery_rollouts=m.recovery_rollouts, refine_scan=m.refine_scan_registration,
                             landmarks=S.Landmarks(occlusion=m.landmark_occlusion, facing=m.landmark_facing),
                             registered_sigma=list(p.eu_registered_sigma))
    loc = S.LocalisationConfig(method=m.relocalization, skip_unregistered_scans=m.skip_unregistered_scans,
                               residual_cap=None if m.registration_residual_cap < 0 else m.registration_residual_cap,
                               fine_stage=m.fine_registration, verified_views=vv)
    mission = S.MissionConfig(max_scans=m.max_scans, max_sim_time=m.max_sim_time, on_collision=m.on_collision,
                              coverage_ceiling=m.coverage_ceiling, stop_unknown_voxels=m.stop_unknown_voxels,
                              stop_min_surface=m.stop_min_surface, stop_min_utility=m.stop_min_utility)
    return S.Scenario(name=o.name, seed=o.seed, robot=_copy(S.RobotConfig, o.robot), scene=scene, sensor=sensor,
                      noise=noise, mapper=_copy(S.MapperConfig, o.mapper), localisation=loc, planner=planner,
                      mission=mission, base_dir=o.base_dir)


def to_old(s: S.Scenario) -> OldScenario:
    """The old flat scenario of today's (what an old setting is applied to). Fields the old
    schema could not express (none of today's) would be lost."""
    p, loc, m = s.planner, s.localisation, s.mission
    o = OldScenario(name=s.name, seed=s.seed, robot=_copy(OldRobotConfig, s.robot),
                    mapper=_copy(OldMapperConfig, s.mapper), base_dir=s.base_dir)
    ob, so = s.scene.object, s.scene
    o.scene = OldSceneConfig(table_size=list(so.table_size), table_height=so.table_height,
                             bbox_min=list(so.bbox_min), bbox_max=list(so.bbox_max), clutter=so.clutter,
                             gt_points=so.gt_points, object=OldObjectConfig(
                                 kind=ob.kind, mesh=ob.mesh or "", xy=list(ob.xy), up=ob.up or "",
                                 rpy_deg=list(ob.rpy_deg), yaw_deg=ob.yaw_deg, tessellation=ob.tessellation,
                                 size=(0.0 if ob.scale is not None else (-1.0 if ob.size is None else ob.size)),
                                 scale=1.0 if ob.scale is None else ob.scale))
    se = s.sensor
    o.sensor = OldSensorConfig(preset=se.preset, **{
        k: (getattr(se, k) if getattr(se, k) is not None else (-1.0 if k.startswith("noise") else 0))
        for k in ("width", "height", "fov_x_deg", "fov_y_deg", "z_near", "z_far", "noise_a", "noise_b")})
    o.noise = OldNoiseConfig(sigma_v=s.noise.sigma_v, sigma_w=s.noise.sigma_w, sigma_arm=list(s.noise.sigma_arm),
                             beta=s.noise.beta)
    op = OldPlannerConfig()
    st = p.strategy
    op.strategy = S.STRATEGY_WORDS[S.variant_name(st)]
    if isinstance(st, S.Ort):
        op.ort_vertices, op.ort_batch = st.vertices, st.batch
    elif isinstance(st, S.ViewSampling):
        op.view_poses = st.poses
    elif isinstance(st, S.ViewCircle):
        op.circle_views, op.circle_range, op.circle_height = st.views, st.range or 0.0, st.height or 0.0
    op.metric, op.coverage_radius = p.metric, p.coverage.radius
    op.n_candidates, op.max_generation_factor, op.max_view_distance = (p.n_candidates, p.max_generation_factor,
                                                                       p.max_view_distance)
    op.overlap_h, op.top_k, op.weights, op.use_distance = p.overlap_h, p.top_k, list(p.weights), p.use_distance
    ev = p.evaluator
    op.ray_stride = ev.stride
    if isinstance(ev, S.Hrt):
        op.hrt_a = ev.a
    else:
        op.coarse_stride, op.refine_views, op.view_occluders = ev.coarse_stride or 0, ev.refine or 0, ev.occluders
    u = p.utility
    op.utility = "eu" if isinstance(u, S.Expected) else "du"
    if isinstance(u, S.Expected):
        op.eu_samples, op.eu_weighting, op.eu_max_collision_rate = u.samples, u.weighting, u.max_collision_rate
        op.eu_free_start, op.eu_alpha, op.eu_gamma = u.free_start, u.alpha, u.gamma
    mp = p.motion_planner
    if isinstance(mp, S.Roadmap):
        op.motion_planner, op.roadmap_vertices, op.roadmap_neighbors = "roadmap", mp.vertices, mp.neighbors
        op.free_goal_heading = mp.free_goal_heading
    else:
        op.motion_planner, op.rrt_max_nodes = "rrt_ext_ext", mp.max_nodes
    op.tree_step = p.tree_step
    op.detour_steering, op.arc_steering = p.steering.detours, p.steering.arcs
    op.map_obstacles, op.max_obstacle_boxes, op.base_clearance = (p.obstacles.map, p.obstacles.max_boxes,
                                                                  p.obstacles.base_clearance)
    op.noise_fallback = p.noise_fallback
    om = OldMissionConfig(max_scans=m.max_scans, max_sim_time=m.max_sim_time, on_collision=m.on_collision,
                          coverage_ceiling=m.coverage_ceiling, stop_unknown_voxels=m.stop_unknown_voxels,
                          stop_min_surface=m.stop_min_surface, stop_min_utility=m.stop_min_utility)
    om.relocalization, om.skip_unregistered_scans = loc.method, loc.skip_unregistered_scans
    om.registration_residual_cap = -1.0 if loc.residual_cap is None else loc.residual_cap
    om.fine_registration = loc.fine_stage
    vv = loc.verified_views
    if vv is not None:
        om.verify_views = True
        om.view_tolerance_m, om.view_tolerance_rad, om.max_recoveries = (vv.tolerance_m, vv.tolerance_rad,
                                                                         vv.max_recoveries)
        om.legs, om.leg_turns = vv.legs is not None, bool(vv.legs and vv.legs.after_turns)
        om.recovery_rollouts, om.refine_scan_registration = vv.recovery_rollouts, vv.refine_scan
        om.landmark_occlusion, om.landmark_facing = vv.landmarks.occlusion, vv.landmarks.facing
        op.eu_registered_sigma = list(vv.registered_sigma)
    o.planner, o.mission = op, om
    return o


#: fields of today's schema removed since (options tried and not adopted; docs/decisions.md),
#: with the one value a scenario written before may hold: a record's or a user's scenario.yaml
#: that names one at that value loads without it; any other value is refused
REMOVED_FIELDS = {("planner", "coverage", "facing_density"): False,
                  ("planner", "coverage", "back_side"): False}


def drop_removed_fields(text: str, doc: dict, what: str = "") -> str:
    """`text` (a scenario YAML document of today's schema, parsed as `doc`) without the
    REMOVED_FIELDS it names at their one possible value; the text unchanged when it names none."""
    named = []
    for path, value in REMOVED_FIELDS.items():
        d = doc
        for key in path[:-1]:
            d = d.get(key) if isinstance(d, dict) else None
        if isinstance(d, dict) and path[-1] in d:
            if d[path[-1]] != value:
                raise ScenarioError(f"{'.'.join(path)} was removed (tried, not adopted: docs/decisions.md); "
                                    f"only {str(value).lower()} is possible{f' in {what}' if what else ''}")
            named.append(path)
    if not named:
        return text
    import yaml
    root = yaml.compose(text)
    for path in named:
        node = root
        for key in path[:-1]:
            node = _child(node, key)
        node.value = [(k, v) for k, v in node.value if not (isinstance(k, yaml.ScalarNode) and k.value == path[-1])]
    return yaml.serialize(root)


def _child(node, key: str):
    """The value node of `key` in a YAML mapping node (None when absent or not a mapping)."""
    import yaml
    if isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            if isinstance(k, yaml.ScalarNode) and k.value == key:
                return v
    return None


def load_old_text(text: str, defaults: OldScenario | None = None) -> OldScenario:
    """An old-schema YAML document (or a fragment of one, merged over `defaults`)."""
    from pydrake.common.yaml import yaml_load_typed
    return yaml_load_typed(schema=OldScenario, data=text, defaults=defaults or OldScenario())


def migrate(text: str) -> S.Scenario:
    """Today's scenario from an old-schema scenario YAML (a record's scenario.yaml): fields the
    document lacks take the old defaults, as they did when it was written."""
    return from_old(load_old_text(text))
