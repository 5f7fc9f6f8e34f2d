"""Scenario configuration: typed dataclasses loaded from YAML with Drake's ``yaml_load_typed``.

A scenario declares one diagram: robot, scene (table, object, bounding box W_box), sensor,
motion noise, mapper, planner and mission. Unknown keys are an error; impossible values are
rejected by :func:`validate` with a one-line message naming the field.
"""



import copy
import dataclasses as dc
import math

from .errors import ScenarioError

# --------------------------------------------------------------------------------------
# Dataclasses (defaults = FACTS.md / Vasquez-Gomez et al. 2017 Table 1 and Table 4)
# --------------------------------------------------------------------------------------


@dc.dataclass
class RobotConfig:
    urdf: str = "patrolbot_katana.urdf"  #: relative to models/ (or absolute)
    #: start state [x, y, theta, q1..q5] (m, rad); the object must be in view from it.
    start: list[float] = dc.field(
        default_factory=lambda: [-1.45, 0.0, 0.0, 0.0, 0.35, -0.35, -0.25, 0.0])
    xy_bounds: list[float] = dc.field(default_factory=lambda: [-1.9, 1.9])
    control_dt: float = 0.1  #: each control u_t is held for this long (s)
    max_linear_velocity: float = 0.3  #: m/s used by the steering function
    max_angular_velocity: float = 0.6  #: rad/s (base)
    max_arm_velocity: float = 0.6  #: rad/s (each arm joint, below the Katana limits)


@dc.dataclass
class ObjectConfig:
    """The object: mesh -> `up` -> `rpy_deg` -> `yaw_deg`, scaled, then set on the table
    (lowest point on the table top, footprint centred at `xy`)."""
    #: "teapot" (Newell's patches), "bunny" (the Stanford bunny, models/stanford_bunny.ply),
    #: "dragon" (the Stanford dragon, models/stanford_dragon.ply) or "mesh" (the file `mesh`)
    kind: str = "teapot"
    mesh: str = ""  #: OBJ/PLY/STL/OFF/glTF/GLB path (relative to the scenario file) when kind = mesh
    #: longest side in metres of the mesh's own (unrotated) bounding box; 0: use `scale` as
    #: is; -1: the kind's default (teapot 0.40, bunny 0.467 and dragon 0.511 = the papers'
    #: scene objects, mesh 0.40). A `kind` changed by a setting (`--set scene.object.kind=...`)
    #: without a `size` (or `up`) setting takes the new kind's defaults (`load_scenario`)
    size: float = -1.0
    scale: float = 1.0  #: mesh units -> metres, used when size = 0
    xy: list[float] = dc.field(default_factory=lambda: [0.0, 0.0])  #: footprint centre on the table
    #: the mesh's up axis: x, y, z, -x, -y or -z; "": the kind's (bunny and dragon y, teapot
    #: and mesh z).
    #: The axes are turned cyclically (x -> y -> z -> x) until `up` is +z (y-up: the mesh's
    #: (x, y, z) become the world's (y, z, x)); a negative axis is then turned 180 deg about x
    up: str = ""
    #: then a rotation about the world's fixed x, y, z axes, in that order (roll, pitch, yaw;
    #: R = Rz(yaw) Ry(pitch) Rx(roll), Drake's RollPitchYaw), degrees
    rpy_deg: list[float] = dc.field(default_factory=lambda: [0.0, 0.0, 0.0])
    yaw_deg: float = 0.0  #: then a turn about the vertical, degrees
    tessellation: int = 12  #: teapot: subdivisions per Bezier patch side


#: per-kind defaults of ObjectConfig.size (when -1) and .up (when "")
OBJECT_KINDS = {"teapot": dict(size=0.40, up="z"), "bunny": dict(size=0.467, up="y"),
                "dragon": dict(size=0.511, up="y"), "mesh": dict(size=0.40, up="z")}
OBJECT_UP_AXES = ("x", "y", "z", "-x", "-y", "-z")


@dc.dataclass
class SceneConfig:
    table_size: list[float] = dc.field(default_factory=lambda: [0.8, 1.0])  #: x, y (m)
    table_height: float = 0.43  #: top surface z (m)
    bbox_min: list[float] = dc.field(default_factory=lambda: [-0.4, -0.4, 0.43])  #: W_box
    bbox_max: list[float] = dc.field(default_factory=lambda: [0.4, 0.4, 0.95])
    clutter: str = "none"  #: "none" or "chairs" (nine chairs around the table, Vasquez-Gomez et al. 2017 Fig. 13)
    object: ObjectConfig = dc.field(default_factory=ObjectConfig)
    gt_points: int = 40000  #: ground-truth surface samples for coverage


@dc.dataclass
class SensorConfig:
    #: "sr4000" (176x144 ToF, 43.6x34.6 deg, 0.4-5 m), "kinect" (640x480, 57x43 deg,
    #: 0.7-6 m, axial noise) or "custom" (all fields below must be set).
    preset: str = "sr4000"
    width: int = 0  #: 0: from the preset
    height: int = 0
    fov_x_deg: float = 0.0
    fov_y_deg: float = 0.0
    z_near: float = 0.0
    z_far: float = 0.0
    #: axial noise sigma_z = noise_a + noise_b (z - 0.4)^2 (m); -1: from the preset
    noise_a: float = -1.0
    noise_b: float = -1.0


SENSOR_PRESETS = {
    "sr4000": dict(width=176, height=144, fov_x_deg=43.6, fov_y_deg=34.6, z_near=0.4,
                   z_far=5.0, noise_a=0.0, noise_b=0.0),
    "kinect": dict(width=640, height=480, fov_x_deg=57.0, fov_y_deg=43.0, z_near=0.7,
                   z_far=6.0, noise_a=0.0012, noise_b=0.0019),
}


@dc.dataclass
class NoiseConfig:
    """Zero-mean Gaussian control noise (Vasquez-Gomez et al. 2017 §6.1), truncated at +-beta sigma."""
    sigma_v: float = 0.00165  #: m/s (Table 4: 1.65 mm/s)
    sigma_w: float = 0.28  #: rad/s (Table 4)
    sigma_arm: list[float] = dc.field(default_factory=lambda: [0.0] * 5)  #: rad/s
    beta: float = 3.0  #: truncation in units of sigma
    #: False (default): a component commanded 0 (omega while the base stands or drives
    #: straight, v while it turns in place, a still joint) is executed exactly and only
    #: commanded velocities get noise, as the authors' own library (vpl) samples it (vpl
    #: generateSampleState: "only if the velocity is non-zero we introduce error") and as
    #: Table 4 was measured (sigma_w from rotations in place, sigma_v from straight drives).
    #: True: every component of every control.
    perturb_zero_commands: bool = False


@dc.dataclass
class MapperConfig:
    voxel_size: float = 0.02
    margin: float = 0.04  #: map = W_box grown by this (x, y, top); the table bounds it below
    prob_hit: float = 0.7  #: OctoMap sensor model
    prob_miss: float = 0.4
    clamp_min: float = 0.1192
    clamp_max: float = 0.971
    free_below: float = 0.45  #: class thresholds: free < 0.45 <= unknown <= 0.55 < occupied
    occupied_above: float = 0.55
    #: points closer than this to the table top are not object points (cloud filter volume)
    table_clearance: float = 0.005


#: the error a registered belief keeps (m, m, rad standard deviations in x, y, heading; the
#: corrected errors measured were mostly below 5 mm and 0.003 rad, at most 1.8 cm and 0.01 rad):
#: planner.eu_registered_sigma's default, the prior of mission.refine_scan_registration and
#: the floor of motion.min_leg_turn
REGISTERED_SIGMA = (0.01, 0.01, 0.01)


@dc.dataclass
class PlannerConfig:
    #: "random_sampling" (Vasquez-Gomez et al. 2017), "ort" (the ORT paper) or "view_sampling"
    #: (Santos et al. 2020 + IK);
    #: baselines: "view_circle" (a fixed circle of views around W_box) or "random_views"
    #: (the first random view that looks at W_box and can be reached; no ranking);
    #: "oracle": the greedy oracle, which knows the true object (planning/oracle.py)
    strategy: str = "random_sampling"
    view_poses: int = 60  #: view_sampling: poses per iteration, spread over the clusters
    #: view_circle: views evenly spaced on a horizontal circle around W_box's centre, each
    #: aimed at the centre (the start scan counts as the first)
    circle_views: int = 12
    #: view_circle: the cameras' horizontal distance from W_box's centre (m); 0: automatic
    #: (0.1 m beyond z_near + W_box's larger half-extent and its footprint corners + 0.15 m:
    #: 0.9 m in the default scene)
    circle_range: float = 0.0
    #: view_circle: the cameras' height (m); 0: automatic (the middle of W_box's upper half)
    circle_height: float = 0.0
    #: information term of the utility: "sur" (Vasquez-Gomez et al. 2017's surface factor,
    #: = VUV / un_total), "fig", "sig", "vuv", "rsv" (the ORT paper; each normalised by the
    #: unknown voxels), "seed001" (Santos et al. 2020's voxel-sorted ray casting score),
    #: "surface" (the share of the view's rays expected to return on new surface: rays that
    #: cross unknown space to known surface, plus those that cross it and leave, weighted by the
    #: chance their unknown stretch holds surface; docs/decisions.md says how it compares)
    #: "coverage" (the covered surface area the view is expected to add, new surface and
    #: denser samples of surface seen too sparsely so far, for the coverage radius below;
    #: view_metrics.M_COVER_GAIN)
    metric: str = "sur"
    #: metric "coverage": a surface point counts as covered when a sample lies within this
    #: distance (m; the papers' coverage threshold, 3 mm)
    coverage_radius: float = 0.003
    ort_vertices: int = 10000  #: ORT tree size k (the ORT paper: 10^4 is the good trade-off)
    #: ORT growth in batches of this many extensions: each batch extends from the tree as it
    #: stood before it and checks its edges in one Drake batch (1: one extension at a time)
    ort_batch: int = 64
    tree_step: float = 1.0  #: tree extension step in the weighted metric of eq. 8
    #: RRT Ext-Ext nodes when no direct steering path reaches a candidate (Table 1: 10^4);
    #: 0: direct steering paths only
    rrt_max_nodes: int = 10000
    #: how the plan's paths to its top candidates are found: "rrt_ext_ext" (Vasquez-Gomez et al.
    #: 2017 §7.4, as the paper ran it: direct steering, then detours when detour_steering, then
    #: one RRT Ext-Ext per candidate with up to rrt_max_nodes vertices, one candidate after the
    #: other) or "roadmap" (planning/roadmap.py: direct steering, then one lazy search of a roadmap
    #: kept for the whole mission for all remaining candidates at once, shortcut; detours only
    #: for the candidates the roadmap does not reach; rrt_max_nodes is not used)
    motion_planner: str = "rrt_ext_ext"
    #: roadmap: free states sampled when the first plan needs the roadmap (it grows by
    #: roadmap.GROWTH_SAMPLES around each candidate it does not reach)
    roadmap_vertices: int = 1500
    roadmap_neighbors: int = 10  #: roadmap: edges to this many nearest vertices (eq. 8 metric)
    #: when no direct steering path reaches a candidate, try paths whose base drives through a
    #: waypoint beside the straight line (motion.steer_via: around the table to the object's
    #: far side) before the RRT; false: the papers' direct steering and RRT Ext-Ext only
    detour_steering: bool = False
    #: direct steering also offers turn-arc-turn (motion.steer_arc: the base turns while it
    #: drives where turn-drive-turn would turn the same way twice); the shortest free path is
    #: taken (roadmap: also its paths' edges); false: the papers' turn-drive-turn only
    arc_steering: bool = False
    #: the roadmap planner may reach a candidate with the base turned about the arm's first
    #: joint and that joint turned back (RobotKinematics.turned_about_mount: the same camera
    #: pose, so the same view) when that makes the path shorter; false: the sampled state itself
    free_goal_heading: bool = False
    n_candidates: int = 4000  #: state samples whose director ray meets W_box
    overlap_h: float = 0.5  #: registration threshold h (Table 1: 50 %)
    top_k: int = 25  #: candidates kept for motion planning (§7.6 step 7)
    weights: list[float] = dc.field(
        default_factory=lambda: [10.0, 10.0, 0.5, 0.05, 0.05, 0.05, 0.05, 0.05])
    use_distance: bool = True
    #: "du": deterministic utility g = pos reg sur dist; "eu": expected utility under the
    #: scenario's control noise (Vasquez-Gomez et al. 2017 Algorithm 1) over the candidates with a path
    utility: str = "du"
    eu_samples: int = 500  #: k rollouts per candidate (Table 7: 500)
    #: how the k rollouts' utilities are combined: "probability" (Algorithm 1 lines 10-12:
    #: weights = normalised products of the m per-step densities; for plans of ~30-100
    #: controls their effective sample size is a few rollouts, so the least-noisy rollout
    #: decides) or "mean" (each rollout is a draw from the error distribution, so the plain
    #: average estimates "the average utility when the robot moves to the indicated state many
    #: times", §7.2)
    eu_weighting: str = "probability"
    #: share of the k rollouts that may collide (with the planning obstacles: the table and
    #: W_box or its unknown voxels) before a candidate is unfeasible; colliding rollouts
    #: count with g = 0. 0: any collision rules the candidate out (Algorithm 1, line 7)
    eu_max_collision_rate: float = 0.0
    #: whether each rollout's utility keeps reg(x) (Vasquez-Gomez et al. 2017's g = pos reg sur dist at the
    #: reached state) or only the candidate itself must pass the registration filter. False
    #: suits re-localisation that also matches the known environment (mission.relocalization:
    #: icp registers against the table too), so a rollout that drifts off the object is
    #: still registered and its scan still counts
    eu_rollout_registration: bool = True
    #: rollouts whose start, a draw of the belief's spread, collides are dropped: the robot
    #: stands free, so those poses are not possible (the belief conditioned on no collision).
    #: False: Algorithm 1 as is, any colliding start makes the candidate unfeasible
    eu_free_start: bool = False
    #: when no candidate is feasible under the motion noise (or none has a path), views from
    #: the current base by the arm alone (exact motion under Table 4's noise) before the run
    #: stops with no_feasible_under_noise (planning/recovery.py)
    noise_fallback: bool = False
    #: the spread (m, m, rad standard deviations in x, y, heading) of a registered belief
    #: that the rollouts of verified views start from (each leg after a localisation frame,
    #: and the recovery paths): the registration's own accuracy. The default,
    #: REGISTERED_SIGMA, is what the open scene's registrations measured (corrected
    #: errors up to ~2 cm); in the cluttered room, with the chairs and the table in the
    #: registration model, they measured 0.5 mm / 0.5 mrad RMS (the `nbvs_reach` cells)
    eu_registered_sigma: list[float] = dc.field(default_factory=lambda: list(REGISTERED_SIGMA))
    eu_alpha: float = 0.01  #: eq. 18: warn when k < log(alpha) / log(1 - eta gamma)
    eu_gamma: float = 0.05
    #: obstacles of the unknown region for pos(x): "wbox" (the whole bounding box) or
    #: "voxels" (the map's unknown and occupied voxels as merged boxes, rebuilt per scan)
    map_obstacles: str = "wbox"
    max_obstacle_boxes: int = 300
    ray_stride: int = 2  #: evaluate every n-th pixel row/column when scoring views
    #: coarse-to-fine view evaluation (planning/views.py, ViewEvaluator.evaluate_ranked): every
    #: candidate is first scored with one ray per coarse_stride x coarse_stride pixel block,
    #: then the best `refine_views` of that ranking again at ray_stride; the ranking's head is
    #: exact, its tail ranked by the coarse pass. 0: every candidate at ray_stride
    coarse_stride: int = 0
    #: coarse_stride: candidates re-scored at ray_stride (0: top_k, the ones motion planning
    #: sees first; else >= top_k)
    refine_views: int = 0
    #: the known environment (the table, the chairs) occludes the views' rays outside the map:
    #: a ray that meets a chair before W_box's map sees the chair (uniform ray tracing only,
    #: hrt_a = 0). False: the map alone decides what a view sees, as in the papers' open scene
    view_occluders: bool = False
    #: the coverage gain (metric "coverage") of a ray that lands on known surface counts the
    #: sample density of the side of the voxel's surface that faces the ray (the points' normals;
    #: planning/views.py facing_density), not of all its samples: a view of a thin part's
    #: unseen side, or of a fold beside a seen one, gains. False: one density per voxel
    facing_density: bool = False
    #: m: the candidates' positions and the motion planner's paths keep the robot's base this
    #: far from the environment and the map's obstacles (Drake's padding on the base link);
    #: the expected utility's rollouts, the recovery paths and the executed motion meet the
    #: true geometry. Under motion noise a path that grazes a chair fails Algorithm 1 (any
    #: colliding rollout) however short it is. 0: off
    base_clearance: float = 0.0
    #: hierarchical ray tracing resolution parameter a (Vasquez-Gomez et al. 2017 §5.4): 0 = uniform ray
    #: tracing; a > 0 starts at voxel size 2^a x voxel_size and refines where needed
    hrt_a: int = 0
    #: candidates' director ray must enter W_box within this distance (m): the working range
    #: where the sensor samples a surface densely enough for the coverage threshold
    #: (SR4000: 4.5 mrad per pixel -> 4.5 mm spacing at 1 m); 0: the sensor's z_far
    max_view_distance: float = 1.0
    max_generation_factor: int = 200  #: at most this many x n_candidates raw samples


@dc.dataclass
class MissionConfig:
    max_scans: int = 12
    max_sim_time: float = 7200.0  #: simulated seconds before the run is cut off
    #: "icp": register each scan against the accumulated model and correct the believed
    #: pose (planar MAP point-to-plane ICP with the motion model's prior); "none": dead reckoning
    relocalization: str = "icp"
    #: a scan whose registration fails (ambiguous, too little of the object in view, poor
    #: fit) is counted but not integrated: a misplaced scan would corrupt the map and the
    #: model the next scans register against; the pose uncertainty carries over to the next
    #: registration's prior
    skip_unregistered_scans: bool = True
    #: after a collision of the executed motion: "stop" the run (the papers' robot
    #: experiments) or "continue" (the collision is counted)
    on_collision: str = "stop"
    #: verified views under motion noise (planning/recovery.py): when a plan that moved the
    #: base ends, a localisation frame (not integrated, not a sensing scan) is registered
    #: first; the scan is taken when the corrected camera is within view_tolerance_m and
    #: view_tolerance_rad of the planned view, else the camera is re-aimed (correction) or,
    #: when the frame cannot be registered, a re-localisation view is taken (recovery); after
    #: max_recoveries such frames the next frame is the scan as it is
    #: report the coverage ceiling (planning/oracle.py: the share of the ground truth any
    #: reachable pose can see; computed once per object, pose, scene and sensor, then cached)
    #: and coverage / ceiling in summary.json
    coverage_ceiling: bool = True
    verify_views: bool = False
    #: with verify_views and motion noise: a plan's path is executed in legs, each ending after
    #: a drive that more base motion follows, with a localisation frame at each leg's end; the
    #: expected utility's rollouts start each leg from its (re-localised) start
    legs: bool = False
    #: with legs: a leg also ends after each turn in place that a drive follows, so the frame
    #: there corrects the heading before the drive (the turn's heading error, up to ~0.4 rad
    #: after a half turn under Table 4, would otherwise move the base sideways over the drive)
    leg_turns: bool = False
    #: with verify_views under noise: a recovery path (the next leg, a correction, a
    #: re-localisation view) must also be free in this many rollouts of its own controls
    #: from the belief's spread (at least the registration's; Algorithm 1's rule, no
    #: collision allowed). 0: only its base shifted by +-2 cm and +-0.02 rad is checked
    recovery_rollouts: int = 0
    #: with verify_views: the sensing scan taken after a correction path (the frame before it
    #: registered, the camera re-aimed) is registered too, with the registration's own
    #: spread (REGISTERED_SIGMA) as its prior, and integrated at that pose where it
    #: registers (else at the belief, as without): a frame registered from a large error can
    #: stop in a wrong minimum that fits (seen at 1.6 cm, 11 mrad, fitness 1.0, after a
    #: 0.25 rad heading error), and a scan merged there corrupts the model every later
    #: registration matches; the scan, re-aimed since, starts from ~1 cm and converges
    refine_scan_registration: bool = False
    view_tolerance_m: float = 0.03
    view_tolerance_rad: float = 0.05
    max_recoveries: int = 3
    #: with verify_views: a registration landmark (the table's and the chairs' surfaces, the
    #: object seen so far) hidden behind a known solid (a chair's back, the table top) does
    #: not count as in view, when a re-localisation view is chosen and when the expected
    #: utility weighs a rollout by the landmarks its frame keeps in view. Without it, views
    #: from outside the chairs' ring were chosen with ~0.9 of the landmarks "in view" and
    #: returned no point of the registration region (docs/decisions.md)
    landmark_occlusion: bool = False
    #: with verify_views: a registration landmark counts as in view only where its surface
    #: faces the camera (the object points' normals, turned towards the camera that saw them;
    #: the environment's exact normals). Without it a re-localisation view from the far side
    #: of the object counts the side seen so far as in view, and its frame returns mostly new
    #: surface (bunny DU-MU seed 9: fitness 0.48, registered 16 mm off, docs/decisions.md)
    landmark_facing: bool = False
    #: m: the registration's fit caps each scan point's residual here, also the cost of a point
    #: on new surface (no model point within the last stage's 2 cm). 0.01 (two point sigmas):
    #: a view from a new side no longer pulls the pose to where its new surface overlaps the
    #: model; 0: the 2 cm, as the paper's settings were measured with; -1 (default): 0.01 with
    #: verify_views (this project's planner under noise), else 0 (docs/decisions.md, "The
    #: registration's residual cap")
    registration_residual_cap: float = -1.0
    #: the registration ends with a finer stage: correspondences within 8 mm (after 2 cm) and a
    #: point-to-plane sigma of 2 mm (not 5 mm) for the robust weights and the fit, for a
    #: noise-free depth sensor such as the SR4000 preset (registration.FINE_STAGE). Without it a
    #: partial overlap biases the pose by 3-10 mm at fitness ~1.0 (dragon EU-MU seed 1: a frame
    #: 1.0 cm off, every later scan 0.8-0.9 cm off), beyond the 3 mm coverage threshold
    fine_registration: bool = False
    #: whether a localisation frame (mission.verify_views) that registered joins the
    #: registration model, as the sensing scans do. False: frames only correct the belief, so
    #: a frame registered a few mm off (a partial view of the object at a leg's end) cannot
    #: bias every later registration
    merge_frames: bool = True
    #: stop when the unknown voxels of W_box fall below this many (0: off; the authors'
    #: library uses 15)
    stop_unknown_voxels: int = 0
    #: stop when the best candidate's information term (sur, or the chosen metric) is below
    #: this (Vasquez-Gomez et al. 2017 §7.5; 0: off)
    stop_min_surface: float = 0.0
    #: stop when the best candidate's utility g (or expected utility) is below this (0: off)
    stop_min_utility: float = 0.0

    def residual_cap(self) -> float:
        """The registration's residual cap in metres (0: the last stage's distance)."""
        if self.registration_residual_cap >= 0:
            return self.registration_residual_cap
        return 0.01 if self.verify_views else 0.0


@dc.dataclass
class Scenario:
    name: str = "default"
    seed: int = 0
    robot: RobotConfig = dc.field(default_factory=RobotConfig)
    scene: SceneConfig = dc.field(default_factory=SceneConfig)
    sensor: SensorConfig = dc.field(default_factory=SensorConfig)
    noise: NoiseConfig = dc.field(default_factory=NoiseConfig)
    mapper: MapperConfig = dc.field(default_factory=MapperConfig)
    planner: PlannerConfig = dc.field(default_factory=PlannerConfig)
    mission: MissionConfig = dc.field(default_factory=MissionConfig)
    #: folder that relative paths (meshes) are resolved against; set by the loader
    base_dir: str = ""


# --------------------------------------------------------------------------------------
# Loading and validation
# --------------------------------------------------------------------------------------


def load_scenario(path=None, *, seed=None, settings=()) -> "Scenario":
    """Loads and validates a scenario YAML: `path` is a file, a built-in scenario's name
    (``"teapot_eu_mu"``) or ``None`` (the built-in default scenario); see
    `resources.scenario_path`. `settings`: overrides "section.field=value" (YAML values, e.g.
    "noise.sigma_w=0.14", "planner.top_k=50", "noise.sigma_arm=[0.01, 0.01, 0, 0, 0]"),
    applied in order."""
    from pydrake.common.yaml import yaml_load_typed

    from .resources import scenario_path
    path = scenario_path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise ScenarioError(f"cannot read scenario file {path}: {e.strerror}") from None
    try:
        scenario = yaml_load_typed(schema=Scenario, data=text, defaults=Scenario())
    except Exception as e:  # yaml_load_typed raises RuntimeError / yaml errors
        msg = " ".join(str(e).split())
        raise ScenarioError(f"malformed scenario {path.name}: {msg}") from None
    if not scenario.base_dir:
        scenario.base_dir = str(path.resolve().parent)
    if seed is not None:
        scenario.seed = int(seed)
    kind = scenario.scene.object.kind
    for setting in settings:
        scenario = apply_setting(scenario, setting)
    _kind_defaults(scenario, kind, settings)
    validate(scenario)
    return scenario


def _kind_defaults(scenario: "Scenario", file_kind: str, settings) -> None:
    """The rule for a kind changed by a setting: a scenario file's `size` and `up` belong to
    its own kind (the default scenario's 0.40 m is the teapot's), so when the settings change
    `scene.object.kind` and set no `size` (no `up`), the new kind's default size (up axis)
    applies: `--set scene.object.kind=bunny` gives the papers' 0.467 m bunny."""
    o = scenario.scene.object
    if o.kind == file_kind:
        return
    keys = {s.partition("=")[0].replace(" ", "") for s in settings}
    if "scene.object.size" not in keys and "scene.object.scale" not in keys:
        o.size = -1.0
    if "scene.object.up" not in keys:
        o.up = ""


def apply_setting(scenario: "Scenario", setting: str) -> "Scenario":
    """A copy of `scenario` with one "dotted.key=value" setting applied (the value is YAML),
    loaded through the same typed schema as the file, so unknown keys and wrong types are
    refused with a ScenarioError naming the setting."""
    from pydrake.common.yaml import yaml_load_typed

    key, sep, value = setting.partition("=")
    parts = [k.strip() for k in key.split(".")]
    value = value.strip()
    if not sep or not all(parts) or not value or "\n" in value:
        raise ScenarioError(f"setting {setting!r}: expected section.field=value, e.g. noise.sigma_w=0.14")
    text = "".join(f"{'  ' * i}{k}:\n" for i, k in enumerate(parts[:-1]))
    text += f"{'  ' * (len(parts) - 1)}{parts[-1]}: {value}\n"
    try:
        return yaml_load_typed(schema=Scenario, data=text, defaults=scenario)
    except Exception as e:  # noqa: BLE001 - yaml_load_typed raises RuntimeError / ValueError / TypeError
        raise ScenarioError(f"setting {setting!r}: {' '.join(str(e).split())}") from None


def resolve_sensor(sensor: SensorConfig) -> SensorConfig:
    """Returns a copy with every preset-derived field filled in."""
    s = copy.deepcopy(sensor)
    if s.preset != "custom":
        if s.preset not in SENSOR_PRESETS:
            raise ScenarioError(
                f"sensor.preset must be one of {sorted(SENSOR_PRESETS) + ['custom']}, got {s.preset!r}")
        for k, v in SENSOR_PRESETS[s.preset].items():
            cur = getattr(s, k)
            if (isinstance(v, int) and cur == 0) or (k.startswith("noise") and cur < 0) or \
                    (not k.startswith("noise") and isinstance(v, float) and cur == 0.0):
                setattr(s, k, v)
    return s


def _require(cond: bool, msg: str):
    if not cond:
        raise ScenarioError(msg)


def _finite(*xs) -> bool:
    return all(isinstance(x, (int, float)) and math.isfinite(x) for x in xs)


def validate(sc: Scenario) -> Scenario:
    """Raises ScenarioError naming the first impossible value."""
    r, s, n, m, p = sc.robot, sc.scene, sc.noise, sc.mapper, sc.planner
    _require(len(r.start) == 8 and _finite(*r.start),
             f"robot.start must be 8 finite numbers [x, y, theta, q1..q5], got {r.start}")
    _require(len(r.xy_bounds) == 2 and r.xy_bounds[0] < r.xy_bounds[1],
             f"robot.xy_bounds must be [min, max] with min < max, got {r.xy_bounds}")
    for k in ("control_dt", "max_linear_velocity", "max_angular_velocity", "max_arm_velocity"):
        v = getattr(r, k)
        _require(_finite(v) and v > 0, f"robot.{k} must be > 0, got {v}")

    _require(len(s.bbox_min) == 3 and len(s.bbox_max) == 3,
             "scene.bbox_min and scene.bbox_max must have 3 numbers each")
    _require(all(a < b for a, b in zip(s.bbox_min, s.bbox_max)),
             f"scene bounding box is empty: bbox_min {s.bbox_min} must be below bbox_max {s.bbox_max}")
    _require(len(s.table_size) == 2 and all(v > 0 for v in s.table_size),
             f"scene.table_size must be two positive numbers, got {s.table_size}")
    _require(s.table_height > 0, f"scene.table_height must be > 0, got {s.table_height}")
    _require(s.clutter in ("none", "chairs"), f"scene.clutter must be 'none' or 'chairs', got {s.clutter!r}")
    _require(s.gt_points >= 100, f"scene.gt_points must be >= 100, got {s.gt_points}")
    o = s.object
    _require(o.kind in OBJECT_KINDS,
             f"scene.object.kind must be one of {', '.join(OBJECT_KINDS)}, got {o.kind!r}")
    _require(o.kind != "mesh" or o.mesh, "scene.object.kind is 'mesh' but scene.object.mesh is empty")
    _require(_finite(o.size) and (o.size >= 0 or o.size == -1),
             f"scene.object.size must be > 0, 0 (use scale) or -1 (the kind's default), got {o.size}")
    _require(_finite(o.scale) and o.scale > 0, f"scene.object.scale must be > 0, got {o.scale}")
    _require(o.up in OBJECT_UP_AXES + ("",),
             f"scene.object.up must be one of x, y, z, -x, -y, -z, got {o.up!r}")
    _require(len(o.rpy_deg) == 3 and _finite(*o.rpy_deg),
             f"scene.object.rpy_deg must be 3 finite numbers [roll, pitch, yaw] in degrees, got {o.rpy_deg}")
    _require(_finite(o.yaw_deg), f"scene.object.yaw_deg must be finite, got {o.yaw_deg}")
    _require(len(o.xy) == 2, f"scene.object.xy must have 2 numbers, got {o.xy}")
    _require(o.tessellation >= 2, f"scene.object.tessellation must be >= 2, got {o.tessellation}")

    rs = resolve_sensor(sc.sensor)
    _require(rs.width > 0 and rs.height > 0, f"sensor width/height must be > 0, got {rs.width}x{rs.height}")
    _require(0 < rs.fov_x_deg < 180 and 0 < rs.fov_y_deg < 180,
             f"sensor field of view must be in (0, 180) deg, got {rs.fov_x_deg}x{rs.fov_y_deg}")
    _require(0 < rs.z_near < rs.z_far, f"sensor range needs 0 < z_near < z_far, got {rs.z_near}..{rs.z_far}")
    _require(rs.noise_a >= 0 and rs.noise_b >= 0, "sensor noise_a/noise_b must be >= 0")

    for k in ("sigma_v", "sigma_w"):
        v = getattr(n, k)
        _require(_finite(v) and v >= 0, f"noise.{k} must be >= 0 (a standard deviation), got {v}")
    _require(len(n.sigma_arm) == 5 and all(_finite(v) and v >= 0 for v in n.sigma_arm),
             f"noise.sigma_arm must be 5 numbers >= 0, got {n.sigma_arm}")
    _require(_finite(n.beta) and n.beta > 0, f"noise.beta must be > 0 (in sigmas), got {n.beta}")

    _require(m.voxel_size > 0, f"mapper.voxel_size must be > 0, got {m.voxel_size}")
    _require(m.margin >= 0, f"mapper.margin must be >= 0, got {m.margin}")
    _require(0.5 < m.prob_hit < 1, f"mapper.prob_hit must be in (0.5, 1), got {m.prob_hit}")
    _require(0 < m.prob_miss < 0.5, f"mapper.prob_miss must be in (0, 0.5), got {m.prob_miss}")
    _require(0 < m.clamp_min < m.free_below <= 0.5 <= m.occupied_above < m.clamp_max < 1,
             "mapper thresholds need 0 < clamp_min < free_below <= 0.5 <= occupied_above < clamp_max < 1")
    extent = [b - a for a, b in zip(s.bbox_min, s.bbox_max)]
    nvox = 1
    for e in extent:
        nvox *= math.ceil((e + 2 * m.margin) / m.voxel_size)
    _require(nvox <= 20_000_000, f"map too large: {nvox} voxels (raise mapper.voxel_size)")

    _require(p.strategy in ("random_sampling", "ort", "view_sampling", "view_circle", "random_views", "oracle"),
             "planner.strategy must be one of random_sampling, ort, view_sampling, view_circle, random_views, "
             f"oracle, got {p.strategy!r}")
    _require(p.circle_views >= 2, f"planner.circle_views must be >= 2, got {p.circle_views}")
    _require(_finite(p.circle_range) and p.circle_range >= 0,
             f"planner.circle_range must be 0 (automatic) or > 0 (m), got {p.circle_range}")
    _require(_finite(p.circle_height) and (p.circle_height == 0 or p.circle_height > s.table_height),
             f"planner.circle_height must be 0 (automatic) or above the table top ({s.table_height} m), "
             f"got {p.circle_height}")
    if p.strategy == "view_circle" and p.circle_range:
        half = [(b - a) / 2 for a, b in zip(s.bbox_min, s.bbox_max)]
        h = p.circle_height or s.bbox_min[2] + 0.75 * (s.bbox_max[2] - s.bbox_min[2])
        _require(p.circle_range > math.hypot(half[0], half[1]) or not s.bbox_min[2] <= h <= s.bbox_max[2],
                 f"planner.circle_range {p.circle_range} m puts the view circle inside W_box (its footprint corners "
                 f"are {math.hypot(half[0], half[1]):.3f} m from the centre)")
    _require(p.view_poses >= 1, f"planner.view_poses must be >= 1, got {p.view_poses}")
    _require(p.metric in ("surface", "coverage", "sur", "fig", "sig", "vuv", "rsv", "seed001"),
             f"planner.metric must be one of surface, coverage, sur, fig, sig, vuv, rsv, seed001, got {p.metric!r}")
    _require(p.coverage_radius > 0, f"planner.coverage_radius must be > 0 m, got {p.coverage_radius}")
    _require(p.metric != "coverage" or p.hrt_a == 0,
             f"planner.metric coverage needs the exact ray casting (planner.hrt_a 0), got hrt_a {p.hrt_a}")
    _require(p.ort_vertices >= 2, f"planner.ort_vertices must be >= 2, got {p.ort_vertices}")
    _require(p.ort_batch >= 1, f"planner.ort_batch must be >= 1, got {p.ort_batch}")
    _require(p.tree_step > 0, f"planner.tree_step must be > 0, got {p.tree_step}")
    _require(p.motion_planner in ("rrt_ext_ext", "roadmap"),
             f"planner.motion_planner must be 'rrt_ext_ext' or 'roadmap', got {p.motion_planner!r}")
    _require(p.roadmap_vertices >= 10, f"planner.roadmap_vertices must be >= 10, got {p.roadmap_vertices}")
    _require(p.roadmap_neighbors >= 2, f"planner.roadmap_neighbors must be >= 2, got {p.roadmap_neighbors}")
    _require(p.rrt_max_nodes >= 0, f"planner.rrt_max_nodes must be >= 0, got {p.rrt_max_nodes}")
    _require(p.n_candidates > 0, f"planner.n_candidates must be > 0, got {p.n_candidates}")
    _require(_finite(p.overlap_h) and 0 <= p.overlap_h <= 1,
             f"planner.overlap_h (h) must be in [0, 1], got {p.overlap_h}")
    cap = sc.mission.registration_residual_cap
    _require(cap == -1 or 0 <= cap <= 0.02,
             f"mission.registration_residual_cap must be -1 (auto) or in [0, 0.02] m, got {cap}")
    _require(p.top_k > 0, f"planner.top_k must be > 0, got {p.top_k}")
    _require(p.utility in ("du", "eu"), f"planner.utility must be 'du' or 'eu', got {p.utility!r}")
    _require(p.eu_samples >= 1, f"planner.eu_samples must be >= 1, got {p.eu_samples}")
    _require(p.eu_weighting in ("mean", "probability"),
             f"planner.eu_weighting must be 'mean' or 'probability', got {p.eu_weighting!r}")
    _require(_finite(p.eu_max_collision_rate) and 0 <= p.eu_max_collision_rate < 1,
             f"planner.eu_max_collision_rate must be in [0, 1), got {p.eu_max_collision_rate}")
    _require(0 < p.eu_alpha < 1 and 0 < p.eu_gamma < 0.99,
             f"planner.eu_alpha and eu_gamma must be in (0, 1), got {p.eu_alpha}, {p.eu_gamma}")
    _require(len(p.eu_registered_sigma) == 3 and all(_finite(v) and v >= 0 for v in p.eu_registered_sigma),
             f"planner.eu_registered_sigma must be 3 numbers >= 0 (m, m, rad), got {p.eu_registered_sigma}")
    _require(len(p.weights) == 8 and all(w >= 0 for w in p.weights),
             f"planner.weights must be 8 numbers >= 0, got {p.weights}")
    _require(p.ray_stride >= 1, f"planner.ray_stride must be >= 1, got {p.ray_stride}")
    _require(p.coarse_stride == 0 or p.coarse_stride > p.ray_stride,
             f"planner.coarse_stride must be 0 (off) or more than ray_stride {p.ray_stride}, got {p.coarse_stride}")
    _require(p.coarse_stride == 0 or p.hrt_a == 0,
             f"planner.coarse_stride needs uniform ray tracing (planner.hrt_a = 0), got hrt_a = {p.hrt_a}; "
             f"set planner.coarse_stride=0 to use HRT")
    _require(p.coarse_stride == 0 or p.refine_views == 0 or p.refine_views >= p.top_k,
             f"planner.refine_views must be 0 (top_k) or >= top_k {p.top_k} with coarse_stride, got {p.refine_views}")
    _require(p.map_obstacles in ("wbox", "voxels"),
             f"planner.map_obstacles must be 'wbox' or 'voxels', got {p.map_obstacles!r}")
    _require(p.max_obstacle_boxes >= 1, f"planner.max_obstacle_boxes must be >= 1, got {p.max_obstacle_boxes}")
    _require(0 <= p.hrt_a <= 4, f"planner.hrt_a must be in 0..4, got {p.hrt_a}")
    _require(p.max_generation_factor >= 1, "planner.max_generation_factor must be >= 1")
    _require(p.base_clearance >= 0 and math.isfinite(p.base_clearance),
             f"planner.base_clearance must be a finite distance >= 0 (m), got {p.base_clearance}")
    _require(not (p.view_occluders and p.hrt_a > 0),
             f"planner.view_occluders needs uniform ray tracing (planner.hrt_a = 0), got hrt_a = {p.hrt_a}")
    _require(p.max_view_distance == 0 or p.max_view_distance > rs.z_near,
             f"planner.max_view_distance must be 0 or beyond the sensor's z_near ({rs.z_near}), "
             f"got {p.max_view_distance}")

    _require(sc.mission.max_scans >= 1, f"mission.max_scans must be >= 1, got {sc.mission.max_scans}")
    mi = sc.mission
    _require(mi.max_sim_time > 0, "mission.max_sim_time must be > 0")
    _require(mi.relocalization in ("icp", "none"),
             f"mission.relocalization must be 'icp' or 'none', got {mi.relocalization!r}")
    _require(_finite(mi.view_tolerance_m, mi.view_tolerance_rad) and mi.view_tolerance_m > 0
             and mi.view_tolerance_rad > 0,
             f"mission.view_tolerance_m and view_tolerance_rad must be > 0, got {mi.view_tolerance_m}, "
             f"{mi.view_tolerance_rad}")
    _require(mi.max_recoveries >= 0, f"mission.max_recoveries must be >= 0, got {mi.max_recoveries}")
    _require(mi.recovery_rollouts >= 0, f"mission.recovery_rollouts must be >= 0, got {mi.recovery_rollouts}")
    _require(mi.on_collision in ("stop", "continue"),
             f"mission.on_collision must be 'stop' or 'continue', got {mi.on_collision!r}")
    _require(mi.stop_unknown_voxels >= 0, f"mission.stop_unknown_voxels must be >= 0, got {mi.stop_unknown_voxels}")
    _require(_finite(mi.stop_min_surface) and 0 <= mi.stop_min_surface < 1,
             f"mission.stop_min_surface must be in [0, 1), got {mi.stop_min_surface}")
    _require(_finite(mi.stop_min_utility) and 0 <= mi.stop_min_utility < 1,
             f"mission.stop_min_utility must be in [0, 1), got {mi.stop_min_utility}")
    _require(p.strategy not in ("view_circle", "random_views") or not (mi.stop_min_surface or mi.stop_min_utility),
             f"mission.stop_min_surface/stop_min_utility stop on the best candidate's score; the baseline "
             f"{p.strategy} does not rank its views: set both to 0")
    return sc
