"""OctreeMapper: integrates each scan into the probabilistic occupancy map."""

from __future__ import annotations

import functools
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.perception import PointCloud
from pydrake.systems.framework import LeafSystem

from ..config import Scenario
from ..mapping.occupancy import OccupancyMap
from ..motion import ControlSequence
from ..registration import (EXACT_POSE_VAR, Correction, KnownSolids, RegistrationConfig, RegistrationModel,
                            ScanView, environment_model, motion_prior, region_mask, register_scan)
from ..sensor import axial_noise_sigma, ray_directions
from ..config import resolve_sensor


class ScanReport:
    """Immutable record of the last integrated scan."""

    def __init__(self, scan_index: int = 0, **info):
        self.scan_index = scan_index
        self.info = info

    def __deepcopy__(self, memo):
        return self


def clean_scan(points_xyz: np.ndarray) -> np.ndarray:
    """(N, 3) finite returns of a (3, N) Drake point cloud: pixels with no return (+-inf) and
    NaN depth are dropped, never passed to the map."""
    P = np.asarray(points_xyz, float).T
    return P[np.all(np.isfinite(P), axis=1)]


def no_return_rays(depth: np.ndarray, X_WC: np.ndarray, dirs_cam: np.ndarray, z_far: float) -> np.ndarray:
    """World-frame end points at the sensor's maximum range for the pixels with no return
    (+inf depth: nothing within z_far). Integrated as free-space rays (OctoMap's max-range
    insertion): they clear space but never mark a hit. NaN and too-close pixels are ignored."""
    mask = np.isposinf(np.asarray(depth, float).reshape(-1))
    d = dirs_cam[mask]
    if len(d) == 0:
        return np.zeros((0, 3))
    p_cam = d * (z_far / d[:, 2])[:, None]
    return p_cam @ X_WC[:3, :3].T + X_WC[:3, 3]


def add_depth_noise(points: np.ndarray, X_WC: np.ndarray, sc: Scenario, scan_index: int) -> np.ndarray:
    """Axial noise sigma_z(z) along each ray (the Kinect model; zero for the ToF preset)."""
    o = X_WC[:3, 3]
    z = (points - o) @ X_WC[:3, 2]
    sigma = axial_noise_sigma(sc.sensor, z)
    if not np.any(sigma > 0):
        return points
    rng = np.random.default_rng([sc.seed, 11, scan_index])
    dz = rng.normal(0.0, 1.0, len(points)) * sigma
    return points + (points - o) * (dz / np.maximum(z, 1e-9))[:, None]


class OctreeMapper(LeafSystem):
    """Probabilistic occupancy over W_box (+ margin) with OctoMap's sensor model (log-odds
    hit/miss with clamping; free < 0.45 <= unknown <= 0.55 < occupied). When the controller
    reports that a new plan has finished (idle), it takes one scan: the point cloud (world
    frame, at the believed camera pose), drops invalid returns, registers it against the
    model (mission.relocalization = icp: the known environment plus the earlier scans;
    planar MAP ICP with the executed plan's motion-model prior and the see-through check of
    the whole scan against the known solids, `registration.register_scan`), and integrates it
    at the corrected pose by ray casting from the sensor origin; returns inside W_box above
    the table are object points. The correction is published for the planner's belief. A
    scan whose registration fails is counted but not integrated
    (mission.skip_unregistered_scans), and its plan's pose uncertainty is added to the next
    registration's prior. With exact odometry (no noise) nothing is registered.

    Input ports:
      - point_cloud (abstract PointCloud): the depth camera's cloud in the world frame.
      - camera_pose (abstract RigidTransform): the believed camera pose X_WC.
      - controller_status (3): [plan_id, steps done, idle].
      - depth_image (abstract ImageDepth32F): the same scan's depth image; its no-return
        pixels clear free space up to the maximum range.
      - controls (abstract ControlSequence): the plan just executed (its states and controls
        give the registration's prior).
    Output ports:
      - map (abstract OccupancyMap): the current map (immutable snapshot).
      - scan_report (abstract ScanReport): statistics and timing of the last scan, with the
        registration result.
      - pose_correction (4): [scan index, dx, dy, dyaw] of the last scan (identity when the
        registration was rejected or is off).
      - pose_covariance (9): the believed pose's planar error covariance (dx, dy, dyaw; 3x3
        row-major) since the last registered scan: zero after a registration, the executed
        plans' motion-model spread summed while registrations fail (kept with
        mission.relocalization icp only; zero with none).
    State: abstract map, registration model and report; discrete [last plan scanned],
    correction (4), pending pose covariance since the last registration (3x3).
    """

    def __init__(self, sc: Scenario, dt: float):
        super().__init__()
        self.sc = sc
        empty = OccupancyMap.for_scenario(sc)
        self._pc = self.DeclareAbstractInputPort("point_cloud", AbstractValue.Make(PointCloud()))
        self._pose = self.DeclareAbstractInputPort("camera_pose", AbstractValue.Make(RigidTransform()))
        self._status = self.DeclareVectorInputPort("controller_status", 3)
        from pydrake.systems.sensors import ImageDepth32F
        self._depth = self.DeclareAbstractInputPort("depth_image", AbstractValue.Make(ImageDepth32F()))
        self._dirs = ray_directions(sc.sensor, 1)[0]
        self._z_far = resolve_sensor(sc.sensor).z_far
        self._tau = self.DeclareAbstractInputPort(
            "controls", AbstractValue.Make(ControlSequence.empty(np.array(sc.robot.start, float))))
        self._map = self.DeclareAbstractState(AbstractValue.Make(empty))
        self.reg_cfg = RegistrationConfig()
        self._solids = KnownSolids.of(sc)
        model0 = environment_model(sc, self.reg_cfg) if sc.mission.relocalization == "icp" else RegistrationModel()
        self._model = self.DeclareAbstractState(AbstractValue.Make(model0))
        self._rep = self.DeclareAbstractState(AbstractValue.Make(ScanReport()))
        self._last = self.DeclareDiscreteState(np.array([-1.0]))
        self._corr = self.DeclareDiscreteState(np.zeros(4))
        self._pending = self.DeclareDiscreteState(np.zeros(9))
        self.DeclareStateOutputPort("map", self._map)
        self.DeclareStateOutputPort("scan_report", self._rep)
        self.DeclareStateOutputPort("pose_correction", self._corr)
        self.DeclareStateOutputPort("pose_covariance", self._pending)
        self.DeclarePeriodicUnrestrictedUpdateEvent(dt, 0.0, self._update)

    def _update(self, context, state):
        status = self._status.Eval(context)
        last = context.get_discrete_state(self._last).get_value()[0]
        if status[2] < 0.5 or status[0] <= last:
            return
        t0 = time.perf_counter()
        X_WC = self._pose.Eval(context).GetAsMatrix4()
        cloud = self._pc.Eval(context)
        t_render = time.perf_counter() - t0
        omap: OccupancyMap = context.get_abstract_state(self._map).get_value()
        k = omap.scan_count + 1
        pts = add_depth_noise(clean_scan(cloud.xyzs()), X_WC, self.sc, k)
        free_rays = no_return_rays(self._depth.Eval(context).data, X_WC, self._dirs, self._z_far)
        model: RegistrationModel = context.get_abstract_state(self._model).get_value()
        t1 = time.perf_counter()
        icp = None
        corr = Correction()
        integrate = True
        pending = context.get_discrete_state(self._pending).get_value().reshape(3, 3)
        if self.sc.mission.relocalization == "icp" and omap.scan_count > 0:
            tau: ControlSequence = self._tau.Eval(context)
            prior = pending + motion_prior(tau.states[0], tau.controls, tau.dt, tau.states[-1], self.sc.noise,
                                           np.random.default_rng([self.sc.seed, 13, k]))
            if np.any(np.diag(prior) > EXACT_POSE_VAR):  # else odometry is exact: nothing to correct
                icp = register_scan(pts[region_mask(self.sc, pts, self.reg_cfg)], model, prior, self.reg_cfg,
                                    free_at=functools.partial(omap.free_hits,
                                                              table_clearance=self.sc.mapper.table_clearance),
                                    view=ScanView(X_WC[:3, 3], pts, self._solids))
                if icp.applied:
                    corr = icp.correction
                    pts, free_rays, X_WC = corr.apply_points(pts), corr.apply_points(free_rays), corr.apply_pose(X_WC)
                    pending = np.zeros((3, 3))
                else:
                    pending = prior
                    integrate = not self.sc.mission.skip_unregistered_scans
        t_register = time.perf_counter() - t1
        t1 = time.perf_counter()
        if integrate:
            new, stats = omap.integrate(X_WC[:3, 3], pts, self.sc.mapper.table_clearance, free_rays)
            model = model.merged(pts[region_mask(self.sc, pts, self.reg_cfg)], self.reg_cfg)
        else:
            new, stats = omap.skipped(), {"points": int(len(pts)), "no_return_rays": int(len(free_rays)),
                                          "object_points": 0, "voxels_updated": 0}
        stats["integrated"] = integrate
        t_update = time.perf_counter() - t1
        state.get_mutable_abstract_state(self._map).set_value(new)
        state.get_mutable_abstract_state(self._model).set_value(model)
        state.get_mutable_discrete_state().get_mutable_vector(self._pending).SetFromVector(pending.reshape(-1))
        state.get_mutable_abstract_state(self._rep).set_value(ScanReport(
            new.scan_count, plan_id=int(status[0]), t_sim=context.get_time(),
            render_s=t_render, update_s=t_update, register_s=t_register,
            icp=icp.to_json() if icp is not None else None,
            sensor_origin=X_WC[:3, 3].tolist(), **stats))
        state.get_mutable_discrete_state().get_mutable_vector(self._last).SetFromVector([status[0]])
        state.get_mutable_discrete_state().get_mutable_vector(self._corr).SetFromVector(
            [new.scan_count, corr.dx, corr.dy, corr.dyaw])
