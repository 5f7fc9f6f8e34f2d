"""The scenario schema: one section per component, each a typed dataclass read by Drake's
``yaml_load_typed``. Variants are tagged unions (``!Ort {vertices: 2000}``), "automatic" and
"from the preset" are ``None``. Each section checks its own fields (``check``), naming them by
their nested path. ``docs/configuration.md`` is written from this file (`nbvs config-reference`).

Defaults are the papers' settings (Vasquez-Gomez et al. 2017 Tables 1 and 4, FACTS.md); the
presets in ``config/presets/`` name this project's planners on top of them.
"""


import dataclasses as dc
import math
from typing import Optional, Union

from ..errors import ScenarioError

#: the error a registered belief keeps (m, m, rad standard deviations in x, y, heading): the
#: default spread verified views' rollouts start from, the prior of the re-registered scan
#: after a correction, and the floor of LegRule.min_turn_steps
REGISTERED_SIGMA = (0.01, 0.01, 0.01)

#: per-kind defaults of ObjectConfig.size and .up (when None)
OBJECT_KINDS = {"teapot": dict(size=0.40, up="z"), "bunny": dict(size=0.467, up="y"),
                "dragon": dict(size=0.511, up="y"), "mesh": dict(size=0.40, up="z"),
                "chair": dict(size=0.90, up="z"), "suitcase": dict(size=0.90, up="z"),
                "humanoid": dict(size=0.58, up="z"), "cup": dict(size=0.24, up="z"),
                "crate": dict(size=0.30, up="z"), "stool": dict(size=0.40, up="z"), "lamp": dict(size=0.36, up="z"),
                "mug": dict(size=0.24, up="z"), "stack": dict(size=0.32, up="z"), "arch": dict(size=0.40, up="z")}
#: what the object stands on
SUPPORTS = ("table", "box", "floor")
#: the known obstacles beside the table or support
CLUTTERS = ("none", "chairs", "room", "obstacles")
OBJECT_UP_AXES = ("x", "y", "z", "-x", "-y", "-z")

SENSOR_PRESETS = {
    "sr4000": dict(width=176, height=144, fov_x_deg=43.6, fov_y_deg=34.6, z_near=0.4,
                   z_far=5.0, noise_a=0.0, noise_b=0.0, model_binning=1, coarse_binning=1,
                   recheck_binning=0, refine_multiple=1),
    "kinect": dict(width=640, height=480, fov_x_deg=57.0, fov_y_deg=43.0, z_near=0.7,
                   z_far=6.0, noise_a=0.0012, noise_b=0.0019, model_binning=3, coarse_binning=3,
                   recheck_binning=2, refine_multiple=2),
}

METRICS = ("sur", "fig", "sig", "vuv", "rsv", "seed001", "surface", "coverage")


#: how an automatic W_box is found (scene.bbox_min null): the object model's rule
#: (world.objects.automatic_wbox), registered by the package (nbvs_drake/__init__.py) so that the
#: configuration does not import the models
_WBOX_RULE: list = []


def set_wbox_rule(rule) -> None:
    """Registers rule(scenario) -> (bbox_min, bbox_max), the automatic W_box."""
    _WBOX_RULE[:] = [rule]


def support_clearance(sensor) -> float:
    """The band above the support that is not object points: the sensor's depth error at 1.5 m
    (3 sigma_z of its axial noise and half its disparity step), at least 5 mm."""
    s = sensor.resolved()
    z = 1.5
    err = 3 * (s.noise_a + s.noise_b * (z - 0.4) ** 2)
    if s.faults.baseline_m and s.faults.disparity_step_px:
        fx = s.width / 2.0 / math.tan(math.radians(s.fov_x_deg) / 2.0)
        err += 0.5 * z * z * s.faults.disparity_step_px / (fx * s.faults.baseline_m)
    return round(max(0.005, err), 4)


def require(cond: bool, msg: str) -> None:
    """Raises ScenarioError(msg) unless cond."""
    if not cond:
        raise ScenarioError(msg)


def finite(*xs) -> bool:
    return all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in xs)


def variant_name(v) -> str:
    """A union value's tag: its class name (``Ort``)."""
    return type(v).__name__


# --------------------------------------------------------------------------------------
# The world: robot, scene, sensor, motion noise
# --------------------------------------------------------------------------------------


@dc.dataclass
class RobotConfig:
    """The PatrolBot + Katana 6M180 (models/patrolbot_katana.urdf) and its velocity limits."""
    urdf: str = "patrolbot_katana.urdf"  #: relative to models/ (or absolute)
    #: start state [x, y, theta, q1..q5] (m, rad); the object must be in view from it
    start: list[float] = dc.field(
        default_factory=lambda: [-1.45, 0.0, 0.0, 0.0, 0.35, -0.35, -0.25, 0.0])
    xy_bounds: list[float] = dc.field(default_factory=lambda: [-1.9, 1.9])  #: the base's x and y range (m)
    control_dt: float = 0.1  #: each control u_t is held for this long (s)
    max_linear_velocity: float = 0.3  #: m/s used by the steering function
    max_angular_velocity: float = 0.6  #: rad/s (base)
    max_arm_velocity: float = 0.6  #: rad/s (each arm joint, below the Katana limits)

    def check(self, at: str = "robot") -> None:
        require(len(self.start) == 8 and finite(*self.start),
                f"{at}.start must be 8 finite numbers [x, y, theta, q1..q5], got {self.start}")
        require(len(self.xy_bounds) == 2 and self.xy_bounds[0] < self.xy_bounds[1],
                f"{at}.xy_bounds must be [min, max] with min < max, got {self.xy_bounds}")
        for k in ("control_dt", "max_linear_velocity", "max_angular_velocity", "max_arm_velocity"):
            v = getattr(self, k)
            require(finite(v) and v > 0, f"{at}.{k} must be > 0, got {v}")


@dc.dataclass
class ObjectConfig:
    """The object: mesh -> `up` -> `rpy_deg` -> `yaw_deg`, scaled, then set on its support
    (lowest point on the table top, the box's top or the floor; footprint centred at `xy`)."""
    #: teapot (Newell's patches), bunny (models/stanford_bunny.ply), dragon
    #: (models/stanford_dragon.ply), mesh (the file `mesh`), or one built from primitives
    #: (world/shapes.py): chair (an office chair), suitcase, humanoid (NAO's size), and the
    #: test objects cup (a hollow vessel), crate (an open box), stool (thin legs and rungs) and
    #: lamp (a thin arm and an open shade)
    kind: str = "teapot"
    mesh: Optional[str] = None  #: OBJ/PLY/STL/OFF/glTF/GLB path (relative to the scenario file) for kind mesh
    #: the longest side in metres of the mesh's own bounding box; None: the kind's (teapot 0.40,
    #: bunny 0.467 and dragon 0.511 = the papers' objects, mesh 0.40, chair 0.90, suitcase 0.90,
    #: humanoid 0.58, cup 0.24, crate 0.30, stool 0.40, lamp 0.36). A kind changed by a
    #: setting without a size takes the new kind's default
    size: Optional[float] = None
    scale: Optional[float] = None  #: mesh units -> metres instead of a size (size must then be None)
    xy: list[float] = dc.field(default_factory=lambda: [0.0, 0.0])  #: footprint centre on the support
    #: the mesh's up axis (x, y, z, -x, -y, -z), turned to +z cyclically (x -> y -> z -> x), a
    #: negative axis then turned 180 deg about x; None: the kind's (bunny and dragon y, else z)
    up: Optional[str] = None
    #: then a rotation about the world's fixed x, y, z axes (Drake's RollPitchYaw), degrees
    rpy_deg: list[float] = dc.field(default_factory=lambda: [0.0, 0.0, 0.0])
    yaw_deg: float = 0.0  #: then a turn about the vertical, degrees
    tessellation: int = 12  #: teapot: subdivisions per Bezier patch side

    def resolved_size(self) -> float:
        """The longest side (m), or 0 when `scale` is used."""
        if self.scale is not None:
            return 0.0
        return OBJECT_KINDS[self.kind]["size"] if self.size is None else float(self.size)

    def resolved_up(self) -> str:
        return OBJECT_KINDS[self.kind]["up"] if self.up is None else self.up

    def check(self, at: str = "scene.object") -> None:
        require(self.kind in OBJECT_KINDS, f"{at}.kind must be one of {', '.join(OBJECT_KINDS)}, got {self.kind!r}")
        require(self.kind != "mesh" or bool(self.mesh), f"{at}.kind is 'mesh' but {at}.mesh is not set")
        require(self.size is None or (finite(self.size) and self.size > 0),
                f"{at}.size must be > 0 (m) or null (the kind's), got {self.size}")
        require(self.scale is None or (finite(self.scale) and self.scale > 0),
                f"{at}.scale must be > 0, got {self.scale}")
        require(self.size is None or self.scale is None, f"{at}: set size or scale, not both")
        require(self.up is None or self.up in OBJECT_UP_AXES,
                f"{at}.up must be one of x, y, z, -x, -y, -z, got {self.up!r}")
        require(len(self.rpy_deg) == 3 and finite(*self.rpy_deg),
                f"{at}.rpy_deg must be 3 finite numbers [roll, pitch, yaw] in degrees, got {self.rpy_deg}")
        require(finite(self.yaw_deg), f"{at}.yaw_deg must be finite, got {self.yaw_deg}")
        require(len(self.xy) == 2, f"{at}.xy must have 2 numbers, got {self.xy}")
        require(self.tessellation >= 2, f"{at}.tessellation must be >= 2, got {self.tessellation}")


@dc.dataclass
class SceneConfig:
    """What the object stands on (a table, a box or the floor), the object, the bounding box
    W_box around what is reconstructed, and the known obstacles."""
    #: table (table_size at table_height), box (box_size on the floor) or floor
    support: str = "table"
    table_size: list[float] = dc.field(default_factory=lambda: [0.8, 1.0])  #: x, y (m)
    table_height: float = 0.43  #: top surface z (m)
    box_size: list[float] = dc.field(default_factory=lambda: [0.35, 0.35, 0.30])  #: support box: x, y, height (m)
    #: the support box is reconstructed with the object (part of the unknown object, in W_box,
    #: its surface in the ground truth) instead of being a known obstacle
    box_reconstructed: bool = False
    #: W_box (m); null: around what is reconstructed, grown by bbox_margin on x, y and top,
    #: its bottom on the surface it stands on
    bbox_min: Optional[list[float]] = dc.field(default_factory=lambda: [-0.4, -0.4, 0.43])
    bbox_max: Optional[list[float]] = dc.field(default_factory=lambda: [0.4, 0.4, 0.95])
    bbox_margin: float = 0.05  #: m, for an automatic W_box
    #: none; chairs (nine chairs around the table, Vasquez-Gomez et al. 2017 Fig. 13); room (the
    #: walls of a 4.8 m room and its furniture, as Fig. 3); obstacles (boxes around the object, as Fig. 19)
    clutter: str = "none"
    object: ObjectConfig = dc.field(default_factory=ObjectConfig)  #: the object reconstructed
    gt_points: int = 40000  #: ground-truth surface samples for coverage

    def support_top(self) -> float:
        """The z the object's lowest point rests on."""
        return {"table": self.table_height, "box": self.box_size[2], "floor": 0.0}[self.support]

    def base_z(self) -> float:
        """The z of the surface under what is reconstructed (the support box's top, or the floor
        when the box is reconstructed with the object)."""
        return 0.0 if self.support == "box" and self.box_reconstructed else self.support_top()

    def on_floor(self) -> bool:
        """Whether what is reconstructed stands on the floor (base_z 0)."""
        return self.base_z() == 0.0

    def base_name(self) -> str:
        """What base_z is the top of, in words."""
        return "floor" if self.on_floor() else {"table": "table top", "box": "box's top"}[self.support]

    def check(self, at: str = "scene") -> None:
        require(self.support in SUPPORTS, f"{at}.support must be one of {', '.join(SUPPORTS)}, got {self.support!r}")
        require((self.bbox_min is None) == (self.bbox_max is None),
                f"{at}.bbox_min and {at}.bbox_max must both be set or both null (automatic)")
        if self.bbox_min is not None:
            require(len(self.bbox_min) == 3 and len(self.bbox_max) == 3,
                    f"{at}.bbox_min and {at}.bbox_max must have 3 numbers each")
            require(all(a < b for a, b in zip(self.bbox_min, self.bbox_max)),
                    f"scene bounding box is empty: bbox_min {self.bbox_min} must be below bbox_max {self.bbox_max}")
        require(finite(self.bbox_margin) and self.bbox_margin >= 0, f"{at}.bbox_margin must be >= 0 m")
        require(len(self.table_size) == 2 and all(v > 0 for v in self.table_size),
                f"{at}.table_size must be two positive numbers, got {self.table_size}")
        require(self.table_height > 0, f"{at}.table_height must be > 0, got {self.table_height}")
        require(len(self.box_size) == 3 and all(finite(v) and v > 0 for v in self.box_size),
                f"{at}.box_size must be three positive numbers, got {self.box_size}")
        require(not self.box_reconstructed or self.support == "box",
                f"{at}.box_reconstructed needs {at}.support box, got {self.support!r}")
        require(self.clutter in CLUTTERS, f"{at}.clutter must be one of {', '.join(CLUTTERS)}, got {self.clutter!r}")
        require(self.gt_points >= 100, f"{at}.gt_points must be >= 100, got {self.gt_points}")
        self.object.check(f"{at}.object")


@dc.dataclass
class DepthFaults:
    """A structured-light sensor's faults beyond axial noise (the Kinect v1: Khoshelham &
    Elberink 2012 for the disparity, Nguyen, Izadi & Lovell 2012 for the lateral noise and the
    incidence angle). Each is off at 0 (grazing_deg at 90)."""
    #: projector-to-camera baseline (m, along the image's +x): the projector's shadow beside a
    #: depth step, f b (1/z_near - 1/z_far) pixels wide on the far surface, returns nothing
    baseline_m: float = 0.075
    #: the disparity f b / z is measured in steps of this many pixels: depth comes in steps of
    #: z^2 step / (f b) (about 2.5 cm at 3 m)
    disparity_step_px: float = 0.125
    #: lateral noise sigma (pixels) of the Nguyen et al. model, 0.8 + 0.035 theta / (pi/2 - theta)
    #: at incidence angle theta: each pixel takes the depth of a neighbour that far off
    lateral_px: float = 0.8
    lateral_gain: float = 0.035
    #: no return where the surface is seen at more than this incidence angle (degrees)
    grazing_deg: float = 80.0

    @staticmethod
    def none() -> "DepthFaults":
        """Every fault off."""
        return DepthFaults(baseline_m=0.0, disparity_step_px=0.0, lateral_px=0.0, lateral_gain=0.0, grazing_deg=90.0)

    def any(self) -> bool:
        return bool(self.baseline_m or self.disparity_step_px or self.lateral_px or self.lateral_gain
                    or self.grazing_deg < 90.0)

    def check(self, at: str) -> None:
        require(finite(self.baseline_m, self.disparity_step_px, self.lateral_px, self.lateral_gain, self.grazing_deg)
                and self.disparity_step_px >= 0 and self.lateral_px >= 0 and self.lateral_gain >= 0,
                f"{at}: baseline_m must be finite and disparity_step_px, lateral_px, lateral_gain >= 0")
        require(0 < self.grazing_deg <= 90, f"{at}.grazing_deg must be in (0, 90], got {self.grazing_deg}")


@dc.dataclass
class SensorConfig:
    """The depth camera: a preset, each of whose values a field may replace (None: the preset's)."""
    #: sr4000 (176x144 ToF, 43.6x34.6 deg, 0.4-5 m), kinect (640x480, 57x43 deg, 0.7-6 m, axial
    #: noise) or custom (every field below set)
    preset: str = "sr4000"
    width: Optional[int] = None  #: pixels
    height: Optional[int] = None
    fov_x_deg: Optional[float] = None
    fov_y_deg: Optional[float] = None
    z_near: Optional[float] = None  #: m
    z_far: Optional[float] = None
    noise_a: Optional[float] = None  #: axial noise sigma_z = noise_a + noise_b (z - 0.4)^2 (m)
    noise_b: Optional[float] = None
    #: the planner's model of the sensor casts one ray per block of model_binning x model_binning
    #: pixels times planner.evaluator.stride (the Kinect's 3: 213 x 160 model pixels about
    #: 0.27 deg apart, as the SR4000's 0.25 deg; 1: every pixel)
    model_binning: Optional[int] = None
    #: the planner's coarse pass (planner.evaluator.coarse_stride) counts its stride in blocks
    #: of this many pixels (the Kinect's 3 and the SR4000's 1: one ray per 18 x 18 and 6 x 6
    #: pixels, about 1.5 deg apart; None with preset custom: model_binning)
    coarse_binning: Optional[int] = None
    #: the coarse pass's second look, in blocks of this many pixels: the views whose coarse
    #: rays came near known surface without one landing on it (the registration filter
    #: undecided) are evaluated again at coarse_stride x recheck_binning pixels per ray
    #: (the Kinect's 2: 12 x 12; 0: no second look, the SR4000's; None with preset custom: 0)
    recheck_binning: Optional[int] = None
    #: how many times planner.top_k views the coarse-to-fine evaluation scores again at the
    #: model's full ray count (planner.evaluator.refine, when set, decides instead): the
    #: Kinect's 2 (its ranking against every pixel: Spearman's rho 0.9898 with top_k, 0.9906
    #: with twice, `nbvs bench visibility --sensor kinect`), the SR4000's 1; None with preset
    #: custom: 1
    refine_multiple: Optional[int] = None
    #: structured-light faults (shadows, disparity steps, lateral noise, grazing dropouts);
    #: None: the preset's (the Kinect's; none for the SR4000)
    faults: Optional[DepthFaults] = None

    def resolved(self) -> "SensorConfig":
        """A copy with every field filled in from the preset."""
        if self.preset != "custom":
            require(self.preset in SENSOR_PRESETS,
                    f"sensor.preset must be one of {sorted(SENSOR_PRESETS) + ['custom']}, got {self.preset!r}")
            base = SENSOR_PRESETS[self.preset]
        else:
            base = {}
        vals = {}
        for f in dc.fields(self):
            if f.name == "faults":
                vals["faults"] = self.faults if self.faults is not None else (
                    DepthFaults() if self.preset == "kinect" else DepthFaults.none())
                continue
            if f.name == "preset":
                continue
            v = getattr(self, f.name)
            if v is None and f.name == "coarse_binning" and f.name not in base:
                v = vals["model_binning"]  # (a custom sensor: its model pixels)
            if v is None and f.name == "recheck_binning" and f.name not in base:
                v = 0  # (a custom sensor: no second look)
            if v is None and f.name == "refine_multiple" and f.name not in base:
                v = 1
            if v is None:
                require(f.name in base, f"sensor.{f.name} must be set for preset custom")
                v = base[f.name]
            vals[f.name] = v
        return SensorConfig(preset=self.preset, **vals)

    def check(self, at: str = "sensor") -> None:
        rs = self.resolved()
        require(rs.width > 0 and rs.height > 0, f"{at}.width/height must be > 0, got {rs.width}x{rs.height}")
        require(0 < rs.fov_x_deg < 180 and 0 < rs.fov_y_deg < 180,
                f"{at} field of view must be in (0, 180) deg, got {rs.fov_x_deg}x{rs.fov_y_deg}")
        require(0 < rs.z_near < rs.z_far, f"{at} range needs 0 < z_near < z_far, got {rs.z_near}..{rs.z_far}")
        require(rs.noise_a >= 0 and rs.noise_b >= 0, f"{at}.noise_a/noise_b must be >= 0")
        require(rs.model_binning >= 1, f"{at}.model_binning must be >= 1, got {rs.model_binning}")
        require(rs.coarse_binning >= 1, f"{at}.coarse_binning must be >= 1, got {rs.coarse_binning}")
        require(rs.recheck_binning >= 0, f"{at}.recheck_binning must be >= 0, got {rs.recheck_binning}")
        require(rs.refine_multiple >= 1, f"{at}.refine_multiple must be >= 1, got {rs.refine_multiple}")
        rs.faults.check(f"{at}.faults")


@dc.dataclass
class NoiseConfig:
    """Zero-mean Gaussian control noise (Vasquez-Gomez et al. 2017 §6.1, Table 4), truncated at
    +-beta sigma, on the commanded velocities only (a component commanded 0 is executed
    exactly, as the authors' library samples it and as Table 4 was measured)."""
    sigma_v: float = 0.00165  #: m/s (Table 4: 1.65 mm/s)
    sigma_w: float = 0.28  #: rad/s (Table 4)
    sigma_arm: list[float] = dc.field(default_factory=lambda: [0.0] * 5)  #: rad/s per arm joint
    beta: float = 3.0  #: truncation in units of sigma

    def any(self) -> bool:
        """Whether any control is noisy."""
        return self.sigma_v > 0 or self.sigma_w > 0 or any(v > 0 for v in self.sigma_arm)

    def check(self, at: str = "noise") -> None:
        for k in ("sigma_v", "sigma_w"):
            v = getattr(self, k)
            require(finite(v) and v >= 0, f"{at}.{k} must be >= 0 (a standard deviation), got {v}")
        require(len(self.sigma_arm) == 5 and all(finite(v) and v >= 0 for v in self.sigma_arm),
                f"{at}.sigma_arm must be 5 numbers >= 0, got {self.sigma_arm}")
        require(finite(self.beta) and self.beta > 0, f"{at}.beta must be > 0 (in sigmas), got {self.beta}")


# --------------------------------------------------------------------------------------
# Perception: the map and the localisation
# --------------------------------------------------------------------------------------


@dc.dataclass
class MapperConfig:
    """The probabilistic occupancy map of W_box (OctoMap's sensor model)."""
    voxel_size: float = 0.02  #: m
    margin: float = 0.04  #: map = W_box grown by this (x, y, top); the table bounds it below
    prob_hit: float = 0.7
    prob_miss: float = 0.4
    clamp_min: float = 0.1192
    clamp_max: float = 0.971
    free_below: float = 0.45  #: class thresholds: free < 0.45 <= unknown <= 0.55 < occupied
    occupied_above: float = 0.55
    #: points closer than this to the surface the object stands on are not object points (m);
    #: None: the sensor's depth error at 1.5 m (3 sigma_z and half a disparity step), at least
    #: 5 mm: 5 mm for the SR4000, 14 mm for the Kinect
    table_clearance: Optional[float] = None
    #: the model (mesh and points) leaves out a scan whose returns lie where the other scans
    #: saw through, and theirs where it saw through, more than this share of the time (a scan
    #: its registration misplaced; perception.reconstruction.consistent_scans); 1: every scan
    scan_conflict: float = 0.05

    def check(self, scene: SceneConfig, at: str = "mapper") -> None:
        require(self.voxel_size > 0, f"{at}.voxel_size must be > 0, got {self.voxel_size}")
        require(0 < self.scan_conflict <= 1, f"{at}.scan_conflict must be in (0, 1], got {self.scan_conflict}")
        require(self.margin >= 0, f"{at}.margin must be >= 0, got {self.margin}")
        require(0.5 < self.prob_hit < 1, f"{at}.prob_hit must be in (0.5, 1), got {self.prob_hit}")
        require(0 < self.prob_miss < 0.5, f"{at}.prob_miss must be in (0, 0.5), got {self.prob_miss}")
        require(0 < self.clamp_min < self.free_below <= 0.5 <= self.occupied_above < self.clamp_max < 1,
                f"{at} thresholds need 0 < clamp_min < free_below <= 0.5 <= occupied_above < clamp_max < 1")
        nvox = 1
        for a, b in zip(scene.bbox_min, scene.bbox_max):
            nvox *= math.ceil((b - a + 2 * self.margin) / self.voxel_size)
        require(nvox <= 20_000_000, f"map too large: {nvox} voxels (raise {at}.voxel_size)")


@dc.dataclass
class Legs:
    """A plan's path executed in legs, each ending after a drive that more base motion follows,
    with a localisation frame at each leg's end (only under motion noise)."""
    #: a leg also ends after each long turn in place that a drive follows, so that the frame
    #: corrects the heading before the drive
    after_turns: bool = False
    #: a leg ends after each drive that more base motion follows; False (with after_turns):
    #: only after the long turns. A drive adds little error of its own (sigma_v = 1.65 mm/s),
    #: and the frame after the turn that follows it fixes that turn's heading anyway
    after_drives: bool = True
    #: m; with after_turns, a leg also ends after a shorter turn whose heading spread (3 sigma,
    #: less what a frame leaves) the drive after it would carry more than this sideways;
    #: 0: only the long turns (LegRule, TurnDrift)
    turn_drift: float = 0.0

    def check(self, at: str) -> None:
        require(self.turn_drift >= 0 and math.isfinite(self.turn_drift),
                f"{at}: turn_drift must be a distance >= 0 m (0: off), not {self.turn_drift}")
        require(self.after_drives or self.after_turns,
                f"{at}: legs that end neither after drives nor after turns are one leg; set after_turns "
                f"or after_drives, or no legs")


@dc.dataclass
class Landmarks:
    """Which registration landmarks (the table, the chairs, the object seen so far) count as
    in view when a re-localisation view is chosen and when the expected utility weighs a
    rollout by the landmarks its frame keeps in view."""
    occlusion: bool = False  #: one hidden behind a known solid (a chair's back, the table top) does not
    facing: bool = False  #: one counts only where its surface faces the camera (back-face test)


@dc.dataclass
class VerifiedViews:
    """Verified views (planning/recovery.py): when a plan that moved the base ends, a
    localisation frame (not integrated) is registered first; the scan is taken when the
    corrected camera is within the tolerances of the planned view, else the camera is re-aimed
    (a correction) or, when the frame cannot be registered, a re-localisation view is taken."""
    tolerance_m: float = 0.03  #: camera position tolerance (m)
    tolerance_rad: float = 0.05  #: camera direction tolerance (rad)
    max_recoveries: int = 3  #: frames before the next frame is the scan as it is
    legs: Optional[Legs] = None  #: execute plans in legs (None: one frame at the plan's end)
    #: a recovery path must also be free in this many rollouts of its own controls from the
    #: belief's spread (Algorithm 1's rule); 0: only its base shifted by +-2 cm, +-0.02 rad
    recovery_rollouts: int = 0
    #: the scan after a correction path is registered again from the frame's pose (prior:
    #: REGISTERED_SIGMA) and integrated there: a frame registered from a large error can
    #: stop in a wrong minimum that fits
    refine_scan: bool = False
    landmarks: Landmarks = dc.field(default_factory=Landmarks)  #: which registration landmarks count as in view
    #: the spread (m, m, rad standard deviations in x, y, heading) of a registered belief that
    #: the rollouts of each leg and of the recovery paths start from: the registration's own
    #: accuracy (the open scene's measured up to ~2 cm; the room's, with the chairs in the
    #: registration model, 0.5 mm)
    registered_sigma: list[float] = dc.field(default_factory=lambda: list(REGISTERED_SIGMA))
    #: when no path answers a frame (a correction or the next leg from where a re-localisation
    #: left the robot), plan the next view afresh from the registered belief (once per scan)
    #: instead of taking the scan where the robot stands, aimed at the landmarks, not the object
    replan: bool = False

    def check(self, at: str) -> None:
        require(finite(self.tolerance_m, self.tolerance_rad) and self.tolerance_m > 0 and self.tolerance_rad > 0,
                f"{at}.tolerance_m and tolerance_rad must be > 0, got {self.tolerance_m}, {self.tolerance_rad}")
        require(self.max_recoveries >= 0, f"{at}.max_recoveries must be >= 0, got {self.max_recoveries}")
        require(self.recovery_rollouts >= 0, f"{at}.recovery_rollouts must be >= 0, got {self.recovery_rollouts}")
        if self.legs is not None:
            self.legs.check(f"{at}.legs")
        require(len(self.registered_sigma) == 3 and all(finite(v) and v >= 0 for v in self.registered_sigma),
                f"{at}.registered_sigma must be 3 numbers >= 0 (m, m, rad), got {self.registered_sigma}")


@dc.dataclass
class RegistrationSearch:
    """How the registration searches its prior (registration.register_scan): the grid starts
    along the prior's main axis, and the coarse stage every start runs. Measured on wide priors
    (a frame after a leg, 26 cm and 0.15 rad) in the cluttered room: the search of before (nine
    starts, 1,500 coarse points, 30 coarse iterations, steps to 1 um) took 2.3 s a
    registration, these defaults 0.8 s, with the same errors (docs/decisions.md). The coarse
    stage's starts away from the truth wander in ~5 mm steps for all their iterations; the one
    near it settles within a few."""
    #: starts along the prior's main axis, in its standard deviations (times grid_minor's three)
    grid_major: list[float] = dc.field(default_factory=lambda: [-2.0, -1.0, 0.0, 1.0, 2.0])
    coarse_points: int = 700  #: the coarse stage's scan points (at most)
    coarse_iterations: int = 8  #: the coarse stage's Gauss-Newton iterations (at most)
    #: a stage has converged when no step component exceeds this (m, rad); far_step_tol: the
    #: stages that match a room's walls and furniture
    step_tol: float = 1e-4
    far_step_tol: float = 1e-3

    def check(self, at: str) -> None:
        require(len(self.grid_major) >= 1 and finite(*self.grid_major),
                f"{at}.grid_major must be one or more numbers, got {self.grid_major}")
        require(self.coarse_points >= 100, f"{at}.coarse_points must be >= 100, got {self.coarse_points}")
        require(self.coarse_iterations >= 1, f"{at}.coarse_iterations must be >= 1, got {self.coarse_iterations}")
        require(finite(self.step_tol, self.far_step_tol) and self.step_tol > 0 and self.far_step_tol > 0,
                f"{at}.step_tol and far_step_tol must be > 0, got {self.step_tol}, {self.far_step_tol}")


@dc.dataclass
class LocalisationConfig:
    """Registration of each scan against the model (planar MAP point-to-plane ICP with the
    motion model's prior), and the verified views under motion noise."""
    method: str = "icp"  #: icp, or none (dead reckoning)
    #: a scan whose registration fails is counted but not integrated (a misplaced scan would
    #: corrupt the map and the model the next scans register against)
    skip_unregistered_scans: bool = True
    #: the fit caps each point's residual here (m), also the cost of a point on new surface;
    #: None: 0.01 with verified views, else the last stage's 2 cm
    residual_cap: Optional[float] = None
    #: a finer last stage: correspondences within 8 mm and a 2 mm point-to-plane sigma, for a
    #: noise-free depth sensor (registration.FINE_STAGE)
    fine_stage: bool = False
    #: a scan point matches a model point only where their normals (each turned towards the
    #: camera that saw it) face the same way, in every scene (in a room or among obstacles it
    #: always does): a thin wall's other face (a crate's inside, a cup's) is no match for the
    #: face seen first, whose pull slid registrations by the wall's thickness
    facing_matches: bool = False
    verified_views: Optional[VerifiedViews] = None  #: None: every frame after a plan is the scan
    #: the registration's search; None: the search of before (nine starts, 30 coarse
    #: iterations; in a room or among obstacles registration.KNOWN_WALLS), as records made
    #: before it load
    search: Optional[RegistrationSearch] = None

    def cap(self) -> float:
        """The residual cap in metres (0: the last stage's distance)."""
        if self.residual_cap is not None:
            return self.residual_cap
        return 0.01 if self.verified_views is not None else 0.0

    def check(self, at: str = "localisation") -> None:
        require(self.method in ("icp", "none"), f"{at}.method must be 'icp' or 'none', got {self.method!r}")
        require(self.residual_cap is None or (finite(self.residual_cap) and 0 <= self.residual_cap <= 0.02),
                f"{at}.residual_cap must be in [0, 0.02] m or null, got {self.residual_cap}")
        if self.verified_views is not None:
            self.verified_views.check(f"{at}.verified_views")
        if self.search is not None:
            self.search.check(f"{at}.search")


# --------------------------------------------------------------------------------------
# The planner: strategy, view evaluation, utility, motion planning
# --------------------------------------------------------------------------------------


@dc.dataclass
class RandomSampling:
    """Vasquez-Gomez et al. 2017: random state samples ranked by the utility."""


@dc.dataclass
class Ort:
    """The Object Reconstruction Tree (the ORT paper): a tree of states grown by RRT extension,
    the best vertex taken."""
    vertices: int = 10000  #: tree size k (10^4 is the paper's trade-off)
    #: extensions per batch, each from the tree as it stood before it, edges checked together
    batch: int = 64


@dc.dataclass
class ViewSampling:
    """Santos et al. 2020: conditional random view sampling around the surface's clusters, then IK."""
    poses: int = 60  #: poses per iteration, spread over the clusters


@dc.dataclass
class ViewCircle:
    """Baseline: views evenly spaced on a horizontal circle around W_box's centre, each aimed at
    the centre (the start scan counts as the first)."""
    views: int = 12
    #: the cameras' horizontal distance from W_box's centre (m); None: 0.1 m beyond z_near + W_box's
    #: larger half-extent and its footprint corners + 0.15 m
    range: Optional[float] = None
    height: Optional[float] = None  #: the cameras' height (m); None: the middle of W_box's upper half


@dc.dataclass
class RandomViews:
    """Baseline: the first random view that looks at W_box and can be reached; no ranking."""


@dc.dataclass
class Oracle:
    """The greedy oracle: knows the true object and takes the view that adds the most coverage."""


@dc.dataclass
class Plugin:
    """A user's planner (nbvs_drake.planning.plugins): a class implementing the planner
    interface (`plan(PlanRequest) -> PlanResult`), built as Class(parts, **options) from the
    project's planning parts (`PlannerParts`: the kinematics, the state sampler, the view
    evaluator, the per-plan obstacles, the motion planner, the utility)."""
    #: "package.module:Class", or the name of an entry point of the group nbvs_drake.planners
    entry: str = ""
    #: keyword arguments of the class, each value written as YAML ("0.5", "true", "[1, 2]")
    options: dict[str, str] = dc.field(default_factory=dict)


Strategy = Union[RandomSampling, Ort, ViewSampling, ViewCircle, RandomViews, Oracle, Plugin]
#: each strategy's name in reports (summary.json's "planner"); a plugin's is its entry
STRATEGY_WORDS = {"RandomSampling": "random_sampling", "Ort": "ort", "ViewSampling": "view_sampling",
                  "ViewCircle": "view_circle", "RandomViews": "random_views", "Oracle": "oracle",
                  "Plugin": "plugin"}


@dc.dataclass
class Exact:
    """Uniform ray casting of every candidate view."""
    stride: int = 2  #: one ray per stride x stride pixel block
    #: coarse-to-fine: every candidate first scored at this stride (> stride), then the best
    #: `refine` again at `stride`; None: every candidate at `stride`
    coarse_stride: Optional[int] = None
    #: candidates re-scored at `stride` (None: planner.top_k x sensor.refine_multiple; else >= top_k)
    refine: Optional[int] = None
    #: the known environment (the table, the chairs) occludes rays outside the map: a user in a
    #: cluttered room reaches for it (False: the map alone decides, as in the papers)
    occluders: bool = False

    def check(self, top_k: int, at: str) -> None:
        require(self.stride >= 1, f"{at}.stride must be >= 1, got {self.stride}")
        require(self.coarse_stride is None or self.coarse_stride > self.stride,
                f"{at}.coarse_stride must be more than stride {self.stride}, got {self.coarse_stride}")
        require(self.refine is None or self.refine >= top_k,
                f"{at}.refine must be >= planner.top_k {top_k}, got {self.refine}")


@dc.dataclass
class Hrt:
    """Hierarchical ray tracing (Vasquez-Gomez et al. 2017 §5.4): rays start at voxel size
    2^a x voxel_size and refine where needed."""
    a: int = 1  #: resolution parameter, 1..4
    stride: int = 2  #: one ray per stride x stride pixel block

    def check(self, top_k: int, at: str) -> None:
        require(1 <= self.a <= 4, f"{at}.a must be in 1..4, got {self.a}")
        require(self.stride >= 1, f"{at}.stride must be >= 1, got {self.stride}")


@dc.dataclass
class Deterministic:
    """The deterministic utility g = pos reg sur dist at the candidate itself."""


@dc.dataclass
class Expected:
    """The expected utility under the control noise (Vasquez-Gomez et al. 2017 Algorithm 1)
    over the candidates with a path."""
    samples: int = 500  #: k rollouts per candidate (Table 7: 500)
    #: probability (Algorithm 1 lines 10-12: weights = normalised products of the per-step
    #: densities) or mean (each rollout a draw of the error distribution, plainly averaged)
    weighting: str = "probability"
    #: share of the rollouts that may collide before a candidate is unfeasible (colliding ones
    #: count with g = 0); 0: any collision rules it out (Algorithm 1, line 7)
    max_collision_rate: float = 0.0
    #: rollouts whose start, a draw of the belief's spread, collides are dropped (the robot
    #: stands free); False: any colliding start makes the candidate unfeasible
    free_start: bool = False
    alpha: float = 0.01  #: eq. 18: warn when k < log(alpha) / log(1 - eta gamma)
    gamma: float = 0.05
    #: m: a rollout counts as free only where every robot body keeps this far from the
    #: environment and W_box (the rollouts' start draws are still judged without it); when no
    #: candidate of the ranking is feasible so, random and view sampling make the plan again with
    #: Algorithm 1's rule (0 m; the ORT and the baselines keep the margin). k rollouts miss a
    #: path's rarer errors (a turn's heading 2-3 sigma off); the margin stands for them. 0:
    #: Algorithm 1's rule alone
    clearance: float = 0.0

    def check(self, at: str) -> None:
        require(self.samples >= 1, f"{at}.samples must be >= 1, got {self.samples}")
        require(finite(self.clearance) and 0 <= self.clearance <= 0.5,
                f"{at}.clearance must be a distance in [0, 0.5] m, got {self.clearance}")
        require(self.weighting in ("mean", "probability"),
                f"{at}.weighting must be 'mean' or 'probability', got {self.weighting!r}")
        require(finite(self.max_collision_rate) and 0 <= self.max_collision_rate < 1,
                f"{at}.max_collision_rate must be in [0, 1), got {self.max_collision_rate}")
        require(0 < self.alpha < 1 and 0 < self.gamma < 0.99,
                f"{at}.alpha and gamma must be in (0, 1), got {self.alpha}, {self.gamma}")


@dc.dataclass
class RrtExtExt:
    """Vasquez-Gomez et al. 2017 §7.4: direct steering, then detours (steering.detours), then one
    RRT Ext-Ext per candidate, one candidate after the other."""
    max_nodes: int = 10000  #: RRT vertices per search (Table 1: 10^4); 0: direct steering only


@dc.dataclass
class Roadmap:
    """Direct steering, then one lazy search of a roadmap kept for the whole mission for all
    remaining candidates at once, shortcut; detours only where the roadmap does not reach."""
    vertices: int = 1500  #: free states sampled when the first plan needs it (it grows around misses)
    neighbors: int = 10  #: edges to this many nearest vertices (eq. 8 metric)
    #: a candidate may be reached with the base turned about the arm's first joint and that
    #: joint turned back (the same camera pose) when that makes the path shorter
    free_goal_heading: bool = False

    def check(self, at: str) -> None:
        require(self.vertices >= 10, f"{at}.vertices must be >= 10, got {self.vertices}")
        require(self.neighbors >= 2, f"{at}.neighbors must be >= 2, got {self.neighbors}")


@dc.dataclass
class Steering:
    """The steering function's path shapes beyond the papers' turn-drive-turn."""
    #: when no direct path reaches a candidate, try a base path through a waypoint beside the
    #: straight line (around the table to the object's far side) before the search
    detours: bool = False
    #: also turn-arc-turn (the base turns while it drives); the shortest free path is taken
    arcs: bool = False


@dc.dataclass
class CoverageGain:
    """Settings of the metric `coverage` (the covered surface area a view is expected to add)."""
    radius: float = 0.003  #: a surface point is covered when a sample lies this close (m; the papers' 3 mm)


@dc.dataclass
class Obstacles:
    """What pos(x) and the paths avoid besides the known environment."""
    map: str = "wbox"  #: the unknown region: wbox (the whole box) or voxels (the map's unknown and occupied voxels)
    max_boxes: int = 300  #: voxels: at most this many merged boxes
    #: keep the robot's base this far from the environment and the map's obstacles (m; Drake's
    #: padding); the rollouts, recovery paths and executed motion meet the true geometry
    base_clearance: float = 0.0
    #: keep every other part of the robot (the arm, the camera) this far from the environment
    #: and the map's obstacles (m), in the positions and paths as base_clearance
    arm_clearance: float = 0.0


@dc.dataclass
class PlannerConfig:
    """The next-best-view/state planner."""
    strategy: Strategy = dc.field(default_factory=RandomSampling)  #: how candidate views/states are found
    #: the information term: sur (Vasquez-Gomez et al. 2017's surface factor), fig, sig, vuv,
    #: rsv (the ORT paper), seed001 (Santos et al. 2020), surface (the share of rays expected to
    #: return on new surface) or coverage (the covered surface area the view is expected to add)
    metric: str = "sur"
    coverage: CoverageGain = dc.field(default_factory=CoverageGain)  #: settings of the metric coverage
    n_candidates: int = 4000  #: state samples whose director ray meets W_box
    max_generation_factor: int = 200  #: at most this many x n_candidates raw samples
    #: random and view sampling: draw further rounds of n_candidates until at least this many
    #: candidates are free of the known environment (at most 25 rounds); 0: one round. Among
    #: obstacles (the chairs) 4 % of the draws are free, in the open scene 60 %
    free_candidates: int = 0
    #: the director ray must enter W_box within this distance (m): where the sensor samples
    #: densely enough for the coverage threshold
    max_view_distance: float = 1.0
    overlap_h: float = 0.5  #: registration threshold h (Table 1: 50 %); 0: no overlap filter
    top_k: int = 25  #: candidates kept for motion planning (§7.6 step 7)
    #: the distance weights of eq. 8 (x, y, theta, q1..q5)
    weights: list[float] = dc.field(default_factory=lambda: [10.0, 10.0, 0.5, 0.05, 0.05, 0.05, 0.05, 0.05])
    use_distance: bool = True  #: the dist(x) factor of g
    #: random and view sampling: the dist(x) factor chooses only among the views whose gain (g
    #: without it) is at least (1 - gain_tolerance) x the best reachable view's: 1, among all
    #: (eq. 4 as written); 0, the best gain, the nearest of equal ones (the ORT keeps eq. 4)
    gain_tolerance: float = 1.0
    evaluator: Union[Exact, Hrt] = dc.field(default_factory=Exact)  #: how a view's rays are cast through the map
    #: the utility the candidates with a path are ranked by
    utility: Union[Deterministic, Expected] = dc.field(default_factory=Deterministic)
    #: how the paths to the top candidates are found
    motion_planner: Union[RrtExtExt, Roadmap] = dc.field(default_factory=RrtExtExt)
    tree_step: float = 1.0  #: tree extension step (RRT, ORT) in the weighted metric of eq. 8
    steering: Steering = dc.field(default_factory=Steering)  #: the steering function's path shapes
    obstacles: Obstacles = dc.field(default_factory=Obstacles)  #: what pos(x) and the paths avoid
    #: when no candidate is feasible under the motion noise, views from the current base by the
    #: arm alone before the run stops with no_feasible_under_noise
    noise_fallback: bool = False

    # what the components read
    def is_expected(self) -> bool:
        return isinstance(self.utility, Expected)

    def strategy_name(self) -> str:
        """The strategy's tag (`Ort`)."""
        return variant_name(self.strategy)

    def strategy_word(self) -> str:
        """The strategy's name in reports (`ort`)."""
        if isinstance(self.strategy, Plugin):
            return f"plugin:{self.strategy.entry}"
        return STRATEGY_WORDS[variant_name(self.strategy)]

    def hrt_a(self) -> int:
        """The HRT resolution parameter (0: uniform ray casting)."""
        return self.evaluator.a if isinstance(self.evaluator, Hrt) else 0

    def coarse_stride(self) -> int:
        """The coarse pass's stride (0: none)."""
        return (self.evaluator.coarse_stride or 0) if isinstance(self.evaluator, Exact) else 0

    def refine_views(self, multiple: int = 1) -> int:
        """The views the coarse-to-fine evaluation scores again at stride: evaluator.refine, else
        top_k x `multiple` (the sensor's refine_multiple)."""
        return (self.evaluator.refine or self.top_k * multiple) if isinstance(self.evaluator, Exact) else self.top_k

    def view_occluders(self) -> bool:
        return isinstance(self.evaluator, Exact) and self.evaluator.occluders

    def is_roadmap(self) -> bool:
        return isinstance(self.motion_planner, Roadmap)

    def rrt_max_nodes(self) -> int:
        return self.motion_planner.max_nodes if isinstance(self.motion_planner, RrtExtExt) else 0

    def free_goal_heading(self) -> bool:
        return isinstance(self.motion_planner, Roadmap) and self.motion_planner.free_goal_heading

    def check(self, scene: SceneConfig, sensor: SensorConfig, at: str = "planner") -> None:
        s = self.strategy
        if isinstance(s, Plugin):
            require(bool(s.entry.strip()), f"{at}.strategy: a !Plugin needs its entry, 'package.module:Class' "
                                           f"or an entry point's name (group nbvs_drake.planners)")
        if isinstance(s, Ort):
            require(s.vertices >= 2, f"{at}.strategy.vertices must be >= 2, got {s.vertices}")
            require(s.batch >= 1, f"{at}.strategy.batch must be >= 1, got {s.batch}")
        elif isinstance(s, ViewSampling):
            require(s.poses >= 1, f"{at}.strategy.poses must be >= 1, got {s.poses}")
        elif isinstance(s, ViewCircle):
            require(s.views >= 2, f"{at}.strategy.views must be >= 2, got {s.views}")
            require(s.range is None or (finite(s.range) and s.range > 0),
                    f"{at}.strategy.range must be > 0 (m) or null, got {s.range}")
            require(s.height is None or (finite(s.height) and s.height > scene.base_z()),
                    f"{at}.strategy.height must be above the {scene.base_name()} ({scene.base_z()} m) or null, "
                    f"got {s.height}")
            if s.range is not None:
                half = [(b - a) / 2 for a, b in zip(scene.bbox_min, scene.bbox_max)]
                h = s.height or scene.bbox_min[2] + 0.75 * (scene.bbox_max[2] - scene.bbox_min[2])
                require(s.range > math.hypot(half[0], half[1]) or not scene.bbox_min[2] <= h <= scene.bbox_max[2],
                        f"{at}.strategy.range {s.range} m puts the view circle inside W_box (its footprint "
                        f"corners are {math.hypot(half[0], half[1]):.3f} m from the centre)")
        require(self.metric in METRICS, f"{at}.metric must be one of {', '.join(METRICS)}, got {self.metric!r}")
        require(self.coverage.radius > 0, f"{at}.coverage.radius must be > 0 m, got {self.coverage.radius}")
        require(self.metric != "coverage" or isinstance(self.evaluator, Exact),
                f"{at}.metric coverage needs the exact ray casting ({at}.evaluator !Exact)")
        require(self.n_candidates > 0, f"{at}.n_candidates must be > 0, got {self.n_candidates}")
        require(self.max_generation_factor >= 1, f"{at}.max_generation_factor must be >= 1")
        require(self.free_candidates >= 0, f"{at}.free_candidates must be >= 0, got {self.free_candidates}")
        z_near = sensor.resolved().z_near
        require(finite(self.max_view_distance) and self.max_view_distance > z_near,
                f"{at}.max_view_distance must be beyond the sensor's z_near ({z_near}), got {self.max_view_distance}")
        require(finite(self.overlap_h) and 0 <= self.overlap_h <= 1,
                f"{at}.overlap_h (h) must be in [0, 1], got {self.overlap_h}")
        require(self.top_k > 0, f"{at}.top_k must be > 0, got {self.top_k}")
        require(finite(self.gain_tolerance) and 0 <= self.gain_tolerance <= 1,
                f"{at}.gain_tolerance must be in [0, 1], got {self.gain_tolerance}")
        require(len(self.weights) == 8 and all(w >= 0 for w in self.weights),
                f"{at}.weights must be 8 numbers >= 0, got {self.weights}")
        self.evaluator.check(self.top_k, f"{at}.evaluator")
        if isinstance(self.utility, Expected):
            self.utility.check(f"{at}.utility")
        mp = self.motion_planner
        if isinstance(mp, Roadmap):
            mp.check(f"{at}.motion_planner")
        else:
            require(mp.max_nodes >= 0, f"{at}.motion_planner.max_nodes must be >= 0, got {mp.max_nodes}")
        require(self.tree_step > 0, f"{at}.tree_step must be > 0, got {self.tree_step}")
        o = self.obstacles
        require(o.map in ("wbox", "voxels"), f"{at}.obstacles.map must be 'wbox' or 'voxels', got {o.map!r}")
        require(o.max_boxes >= 1, f"{at}.obstacles.max_boxes must be >= 1, got {o.max_boxes}")
        require(finite(o.base_clearance) and o.base_clearance >= 0,
                f"{at}.obstacles.base_clearance must be a finite distance >= 0 (m), got {o.base_clearance}")
        require(finite(o.arm_clearance) and o.arm_clearance >= 0,
                f"{at}.obstacles.arm_clearance must be a finite distance >= 0 (m), got {o.arm_clearance}")


# --------------------------------------------------------------------------------------
# The mission
# --------------------------------------------------------------------------------------


@dc.dataclass
class MissionConfig:
    """When the mission stops and what it reports."""
    max_scans: int = 12
    max_sim_time: float = 7200.0  #: simulated seconds before the run is cut off
    #: after a collision of the executed motion: stop the run (the papers' robot experiments)
    #: or continue (the collision is counted)
    on_collision: str = "stop"
    #: report the coverage ceiling (the share of the ground truth any reachable pose can see,
    #: cached per object, pose, scene and sensor) and coverage / ceiling
    coverage_ceiling: bool = True
    stop_unknown_voxels: int = 0  #: stop below this many unknown voxels of W_box (0: off; the authors' library: 15)
    #: stop when the best candidate's information term is below this (§7.5; 0: off)
    stop_min_surface: float = 0.0
    stop_min_utility: float = 0.0  #: stop when the best candidate's utility is below this (0: off)

    def check(self, planner: PlannerConfig, at: str = "mission") -> None:
        require(self.max_scans >= 1, f"{at}.max_scans must be >= 1, got {self.max_scans}")
        require(self.max_sim_time > 0, f"{at}.max_sim_time must be > 0")
        require(self.on_collision in ("stop", "continue"),
                f"{at}.on_collision must be 'stop' or 'continue', got {self.on_collision!r}")
        require(self.stop_unknown_voxels >= 0, f"{at}.stop_unknown_voxels must be >= 0, got {self.stop_unknown_voxels}")
        require(finite(self.stop_min_surface) and 0 <= self.stop_min_surface < 1,
                f"{at}.stop_min_surface must be in [0, 1), got {self.stop_min_surface}")
        require(finite(self.stop_min_utility) and 0 <= self.stop_min_utility < 1,
                f"{at}.stop_min_utility must be in [0, 1), got {self.stop_min_utility}")
        name = planner.strategy_name()
        require(name not in ("ViewCircle", "RandomViews") or not (self.stop_min_surface or self.stop_min_utility),
                f"{at}.stop_min_surface/stop_min_utility stop on the best candidate's score; the baseline "
                f"{name} does not rank its views: set both to 0")


@dc.dataclass
class Scenario:
    """One mission: the world, the perception, the planner and the mission's limits. `preset`
    names the preset the file starts from (config/presets/); the file's sections are merged
    over it."""
    name: str = "default"  #: the scenario's name (in reports)
    seed: int = 0  #: every random draw of the run derives from it: same seed, same result
    #: the preset the file starts from (config/presets/: paper, nbvs, nbvs_noise, nbvs_room)
    preset: Optional[str] = None
    robot: RobotConfig = dc.field(default_factory=RobotConfig)  #: the robot and its velocity limits
    scene: SceneConfig = dc.field(default_factory=SceneConfig)  #: the table, the object, W_box, the chairs
    sensor: SensorConfig = dc.field(default_factory=SensorConfig)  #: the depth camera
    noise: NoiseConfig = dc.field(default_factory=NoiseConfig)  #: the control noise
    mapper: MapperConfig = dc.field(default_factory=MapperConfig)  #: the occupancy map
    #: the registration and the verified views
    localisation: LocalisationConfig = dc.field(default_factory=LocalisationConfig)
    planner: PlannerConfig = dc.field(default_factory=PlannerConfig)  #: the next-best-view/state planner
    mission: MissionConfig = dc.field(default_factory=MissionConfig)  #: when the mission stops
    base_dir: str = ""  #: the folder relative paths (meshes) are resolved against; set by the loader

    def check(self) -> "Scenario":
        """Raises ScenarioError naming the first impossible value by its nested path."""
        self.robot.check()
        self.scene.check()
        if self.mapper.table_clearance is None:
            self.mapper.table_clearance = support_clearance(self.sensor)
        if self.scene.bbox_min is None:  # W_box around what is reconstructed
            require(_WBOX_RULE, "scene.bbox_min null needs the object model (import nbvs_drake)")
            self.scene.bbox_min, self.scene.bbox_max = _WBOX_RULE[0](self)
        self.sensor.check()
        self.noise.check()
        self.mapper.check(self.scene)
        self.localisation.check()
        self.planner.check(self.scene, self.sensor)
        self.mission.check(self.planner)
        return self
