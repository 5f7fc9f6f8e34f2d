"""Localisation: the one owner of the robot's belief (state and planar pose covariance)."""

from __future__ import annotations

import functools
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.perception import PointCloud
from pydrake.systems.framework import BasicVector, LeafSystem, ValueProducer

from ..config import LocalisationConfig, MapperConfig, NoiseConfig, Scenario, SceneConfig, SensorConfig, resolve_sensor
from ..mapping.occupancy import OccupancyMap
from ..perception.registration import (
    KnownSolids,
    RegistrationModel,
    ScanView,
    environment_model,
    motion_prior,
    region_mask,
    register_scan,
    registration_config,
)
from ..stage_clock import REGISTRATION, VERIFICATION, stage
from ..world.motion import REGISTERED_SIGMA, ControlSequence
from ..world.pose import EXACT_POSE_VAR, Correction
from ..world.robot import RobotKinematics
from ..world.sensor import binned_cloud, clean_scan, no_return_rays, ray_directions
from ..world.state import NQ
from .messages import Belief, ControllerStatus, RegisteredScan


class _Memory:
    """Immutable state: the belief (its covariance: the pose spread no registration has removed
    yet), the plan it last predicted from, the last plan scanned, the registration model, the
    last scan."""

    def __init__(self, belief: Belief, predicted_plan: int, scanned_plan: int, model: RegistrationModel,
                 last_scan: RegisteredScan, frames: tuple = ()):
        self.belief = belief
        self.predicted_plan = predicted_plan
        self.scanned_plan = scanned_plan
        self.model = model
        self.last_scan = last_scan
        #: the localisation frames since the last sensing scan (their reports)
        self.frames = frames

    def __deepcopy__(self, memo):
        return self


class _Outcome:
    """The registered scan and the memory after it (None when no scan is due)."""

    def __init__(self, scan: RegisteredScan, memory: _Memory | None):
        self.scan = scan
        self.memory = memory

    def __deepcopy__(self, memo):
        return self


def _recoveries(frames, per_leg: bool) -> int:
    """The localisation frames mission.max_recoveries bounds: those not at a leg's end since
    the scan, or (per_leg: mission.leg_turns, whose plans have twice the legs) since the last
    leg's frame, so each leg has its own budget."""
    n = 0
    for f in reversed(frames):
        if f.get("purpose") == "leg":
            if per_leg:
                break
            continue
        n += 1
    return n


class Localisation(LeafSystem):
    """Registers each scan and holds the belief. While a plan executes the belief is its
    predicted end state (dead reckoning). When the controller reports that a new plan has
    finished (idle), the scan is taken: the point cloud (world frame at the believed camera
    pose) without invalid returns, and the no-return pixels as maximum-range rays; with
    localisation.method = icp it is registered against the registration model (the known
    environment plus the earlier registered scans: planar MAP point-to-plane ICP with the
    executed plan's motion-model prior and the see-through check against the known solids and
    the map's free space, `registration.register_scan`), and the belief is corrected. A scan
    whose registration fails keeps the odometry; its plan's pose spread carries over to the
    next registration's prior and to the planner (the covariance), and with
    localisation.skip_unregistered_scans the scan is handed on marked not to be integrated. With
    exact odometry (no noise) nothing is registered.

    With mission.verify_views (planning/recovery.py) the frame at the end of a plan that moved
    the base is first a localisation frame: it is the sensing scan only when it registers and
    the corrected camera is within the tolerances of the plan's target view; otherwise the
    belief is corrected (or keeps its spread), `Belief.check` asks the planner for a
    correction or a re-localisation view, and the frame is neither integrated nor counted (its
    report goes with the next sensing scan's, `frames`). A plan with purpose "correct" (the
    arm alone, exact) ends in the sensing scan, and so does the frame after
    mission.max_recoveries localisation frames (with mission.leg_turns, per leg).

    Input ports:
      - point_cloud (abstract PointCloud): the depth camera's cloud, world frame at the
        believed camera pose.
      - depth_image (abstract ImageDepth32F): the same scan's depth image (its no-return
        pixels clear free space up to the maximum range).
      - controller_status (3): `ControllerStatus`.
      - controls (abstract ControlSequence): the current plan (its states predict the
        belief; its controls give the registration's motion prior).
      - map (abstract OccupancyMap): the map of the earlier scans (the free space the
        registration must not put surface into).
    Output ports:
      - registered_scan (abstract RegisteredScan): the newest scan at its corrected pose;
        computed when the scan is due, so the mapper integrates it at the same tick.
      - belief (abstract Belief): scan index, dead-reckoned and corrected state, covariance.
      - believed_state (8): the believed state (for the believed camera pose).
    State: abstract (belief with its covariance, registration model, last scan).
    """

    @staticmethod
    def for_scenario(sc: Scenario, kin: RobotKinematics, q0, dt: float) -> "Localisation":
        """The localisation of a scenario: its own section, and the scene (the known
        environment), sensor, mapper and noise sections it registers with."""
        return Localisation(sc.localisation, sc.scene, sc.sensor, sc.mapper, sc.noise, kin, q0, dt, sc.seed)

    def __init__(self, config: LocalisationConfig, scene: SceneConfig, sensor: SensorConfig, mapper: MapperConfig,
                 noise: NoiseConfig, kin: RobotKinematics, q0, dt: float, seed: int):
        super().__init__()
        self.config, self.scene, self.mapper, self.noise, self.seed = config, scene, mapper, noise, seed
        self.reg_cfg = registration_config(config, scene)
        vv = config.verified_views
        self._leg_turns = bool(vv is not None and vv.legs is not None and vv.legs.after_turns)
        self._solids = KnownSolids.of(scene)
        self._dirs = ray_directions(sensor, 1)[0]
        rs = resolve_sensor(sensor)
        self._z_far = rs.z_far
        self._image_size, self._binning = (rs.width, rs.height), rs.model_binning
        q0 = np.asarray(q0, float)
        model0 = environment_model(scene, self.reg_cfg) if config.method == "icp" else RegistrationModel()
        mem = _Memory(Belief.exact(q0), 0, -1, model0, RegisteredScan())
        self._pc = self.DeclareAbstractInputPort("point_cloud", AbstractValue.Make(PointCloud()))
        from pydrake.systems.sensors import ImageDepth32F
        self._depth = self.DeclareAbstractInputPort("depth_image", AbstractValue.Make(ImageDepth32F()))
        self._status = self.DeclareVectorInputPort("controller_status", ControllerStatus.SIZE)
        self._tau = self.DeclareAbstractInputPort("controls", AbstractValue.Make(ControlSequence.empty(q0, dt)))
        self._map = self.DeclareAbstractInputPort("map", AbstractValue.Make(OccupancyMap.for_scene(scene, mapper)))
        self._mem = self.DeclareAbstractState(AbstractValue.Make(mem))
        self._kin = kin
        self._outcome = self.DeclareCacheEntry(
            "scan_outcome", ValueProducer(allocate=lambda: AbstractValue.Make(_Outcome(RegisteredScan(), None)),
                                          calc=self._calc_outcome), {self.all_sources_ticket()})
        self.DeclareAbstractOutputPort("registered_scan", lambda: AbstractValue.Make(RegisteredScan()),
                                       self._calc_scan, {self._outcome.ticket()})
        self.DeclareAbstractOutputPort("belief", lambda: AbstractValue.Make(mem.belief), self._calc_belief,
                                       {self.abstract_state_ticket(self._mem)})
        self.DeclareVectorOutputPort("believed_state", NQ, self._calc_believed_state,
                                     {self.abstract_state_ticket(self._mem)})
        self.DeclarePeriodicUnrestrictedUpdateEvent(dt, 0.0, self._update)

    def _mem_of(self, context) -> _Memory:
        return context.get_abstract_state(self._mem).get_value()

    def _scan_due(self, context, mem: _Memory) -> ControllerStatus | None:
        status = ControllerStatus.of(self._status.Eval(context))
        return status if status.idle and status.plan_id > mem.scanned_plan else None

    def _register(self, context, mem: _Memory, status: ControllerStatus):
        """(the registered scan, the corrected belief, the registration model)."""
        t0 = time.perf_counter()
        X_WC = self._kin.camera_poses(mem.belief.state)[0]
        cloud = self._pc.Eval(context)
        t_render = time.perf_counter() - t0
        k = mem.belief.scan + 1
        pts = clean_scan(cloud.xyzs())
        # the registration works on the model's pixels (sensor.model_binning: one pixel per
        # 3 x 3 block of the Kinect, as many returns as the SR4000 gives; the map takes them all)
        reg_pts = pts if self._binning == 1 else clean_scan(binned_cloud(cloud.xyzs(), self._image_size, self._binning))
        free_rays = no_return_rays(self._depth.Eval(context).data, X_WC, self._dirs, self._z_far)
        t1 = time.perf_counter()
        icp = None
        corr = Correction()
        integrate = True
        pending = mem.belief.covariance
        tau: ControlSequence = self._tau.Eval(context)
        check = ""
        if self.config.method == "icp" and mem.belief.scan > 0:
            prior = pending + motion_prior(tau.states[0], tau.controls, tau.dt, tau.states[-1], self.noise,
                                           np.random.default_rng([self.seed, 13, k] + (
                                               [len(mem.frames)] if mem.frames else [])))
            refine = self._refines(tau, mem)
            if refine:  # the scan after a correction: registered again from the frame's pose
                prior = prior + np.diag(np.square(REGISTERED_SIGMA))
            if np.any(np.diag(prior) > EXACT_POSE_VAR):  # else odometry is exact: nothing to correct
                omap: OccupancyMap = self._map.Eval(context)
                icp = register_scan(reg_pts[region_mask(self.scene, reg_pts, self.reg_cfg)], mem.model, prior,
                                    self.reg_cfg, free_at=functools.partial(omap.free_hits,
                                                                            table_clearance=self.mapper.table_clearance),
                                    view=ScanView(X_WC[:3, 3], reg_pts, self._solids))
                if icp.applied:
                    corr = icp.correction
                    pts, free_rays, X_WC = corr.apply_points(pts), corr.apply_points(free_rays), corr.apply_pose(X_WC)
                    reg_pts = corr.apply_points(reg_pts)
                    pending = np.zeros((3, 3))
                elif not refine:
                    pending = prior
                    integrate = not self.config.skip_unregistered_scans
                # (a refining registration that fails leaves the scan at the registered frame's pose)
                check = self._verify(tau, icp, corr.apply_state(mem.belief.state),
                                     _recoveries(mem.frames, self._leg_turns))
        t_register = time.perf_counter() - t1
        model = mem.model
        if integrate and (not check or icp.applied):
            model = model.merged(reg_pts[region_mask(self.scene, reg_pts, self.reg_cfg)], self.reg_cfg, X_WC[:3, 3])
        dead = mem.belief.state
        frame = dict(plan_id=status.plan_id, purpose=tau.purpose, n_controls=int(tau.m), t_sim=context.get_time(),
                     register_s=round(t_register, 4), icp=icp.to_json() if icp is not None else None)
        if check:  # a localisation frame: the belief moves on, the map and the scan count do not
            frame["check"] = check
            belief = Belief(mem.belief.scan, dead, corr.apply_state(dead), pending, mem.belief.frame + 1, check)
            scan = RegisteredScan(mem.belief.scan, X_WC[:3, 3], pts[:0], free_rays[:0], False, {})
            return scan, belief, model, mem.frames + (frame,)
        info = dict(plan_id=status.plan_id, t_sim=context.get_time(), render_s=t_render, register_s=t_register,
                    icp=frame["icp"])
        if self.config.verified_views is not None:
            info["frames"] = list(mem.frames)
        scan = RegisteredScan(k, X_WC[:3, 3], pts, free_rays, integrate, info, X_WC)
        belief = Belief(k, dead, corr.apply_state(dead), pending, mem.belief.frame + 1, "")
        return scan, belief, model, ()

    def _refines(self, tau: ControlSequence, mem) -> bool:
        """mission.refine_scan_registration: this scan ends a correction path of verified views."""
        mi = self.config.verified_views
        return bool(mi is not None and mi.refine_scan and tau.purpose == "correct" and mem.frames)

    def _verify(self, tau: ControlSequence, icp, corrected: np.ndarray, n_frames: int) -> str:
        """What a frame at the end of plan tau asks for under mission.verify_views: "" (it is
        the sensing scan), "relocalise" (not registered) or "correct" (registered, but the
        corrected camera is off tau's target view)."""
        mi = self.config.verified_views
        if mi is None or tau.purpose == "correct" or tau.target is None or \
                (n_frames >= mi.max_recoveries and tau.purpose != "leg"):
            return ""
        if icp is None or not icp.applied:
            return "relocalise"
        if tau.purpose in ("relocalise", "leg"):  # not at the view yet: on to it
            return "correct"
        from ..planning.recovery import camera_error
        d, a = camera_error(self._kin, corrected, tau.target)
        return "correct" if d > mi.tolerance_m or a > mi.tolerance_rad else ""

    def _calc_outcome(self, context, value):
        """The due scan's registration and the memory after it (None: no scan due), cached:
        the mapper's input and this system's update read the same result."""
        mem = self._mem_of(context)
        status = self._scan_due(context, mem)
        if status is None:
            value.set_value(_Outcome(mem.last_scan, None))
            return
        with stage(REGISTRATION, "sensing_scan") as st:
            scan, belief, model, frames = self._register(context, mem, status)
            if belief.check:  # a localisation frame
                st.name, st.part = VERIFICATION, "frame_registration"
        value.set_value(_Outcome(scan, _Memory(belief, mem.predicted_plan, status.plan_id, model,
                                               scan if not belief.check else mem.last_scan, frames)))

    def _calc_scan(self, context, output):
        output.set_value(self._outcome.Eval(context).scan)

    def _update(self, context, state):
        mem = self._mem_of(context)
        new = self._outcome.Eval(context).memory
        if new is None:
            tau: ControlSequence = self._tau.Eval(context)
            if tau.plan_id <= mem.predicted_plan:
                return
            # a new plan: the belief is its predicted end state until the next scan corrects it
            b = mem.belief
            new = _Memory(Belief(b.scan, b.dead_reckoned, tau.states[-1], b.covariance, b.frame, ""), tau.plan_id,
                          mem.scanned_plan, mem.model, mem.last_scan, mem.frames)
        state.get_mutable_abstract_state(self._mem).set_value(new)

    def _calc_belief(self, context, output):
        output.set_value(self._mem_of(context).belief)

    def _calc_believed_state(self, context, output: BasicVector):
        output.SetFromVector(self._mem_of(context).belief.state)
