"""SurfaceFusion: the object's surface mesh by TSDF fusion of the registered depth scans."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from ..config import MapperConfig, SceneConfig, SensorConfig, resolve_sensor
from ..perception.reconstruction import consistent_scans, depth_from_points, fuse_tsdf
from ..stage_clock import MAP, stage
from ..world.sensor import axial_noise_sigma, intrinsics
from .messages import RegisteredScan


class _Scans:
    """Immutable state: the last scan index seen and the integrated scans as (X_WC, depth)."""

    def __init__(self, index: int = 0, scans: tuple = ()):
        self.index = index
        self.scans = scans

    def __deepcopy__(self, memo):
        return self


class SurfaceFusion(LeafSystem):
    """Keeps every integrated scan as a depth image at its registered camera pose (the returns
    within W_box grown by `margin`, re-projected with the sensor's intrinsics) and gives the
    surface mesh of their TSDF fusion (`reconstruction.fuse_tsdf`: 3 mm voxels, 12 mm
    truncation), cropped to W_box from `mapper.table_clearance` above the table top: the
    table is not part of the model. A scan not integrated (its registration failed) is left
    out, as the map leaves it out, and so is a scan that disagrees with the others (its
    returns where they saw through, theirs where it saw through: a scan its registration
    misplaced; `reconstruction.consistent_scans`, above `mapper.scan_conflict`).

    Input ports:
      - registered_scan (abstract RegisteredScan): the newest scan at its registered pose.
    Output ports:
      - mesh (abstract tuple (vertices (V, 3), triangles (T, 3))): the fused surface of the
        scans that agree.
      - left_out (abstract dict {scan number (0: the first integrated): conflict share}): the
        scans the mesh leaves out.
      - scans (abstract tuple of (X_WC (4, 4), depth (h, w))): every integrated scan.
    State: abstract (the scans kept).
    """

    def __init__(self, scene: SceneConfig, mapper: MapperConfig, sensor: SensorConfig, dt: float,
                 voxel: float = 0.003, margin: float = 0.05):
        """`scene`: W_box and the table (the crop); `mapper`: the table clearance; `sensor`: the
        depth camera's intrinsics and range."""
        super().__init__()
        self.voxel = voxel
        s = scene
        self._lo = np.array([s.bbox_min[0] - margin, s.bbox_min[1] - margin, s.base_z() - margin])
        self._hi = np.array(s.bbox_max, float) + margin
        self.crop_min = np.array([s.bbox_min[0], s.bbox_min[1], s.base_z() + mapper.table_clearance])
        self.crop_max = np.array(s.bbox_max, float)
        self._intr = intrinsics(sensor)
        self._z_far = resolve_sensor(sensor).z_far
        self._sigma = lambda z: axial_noise_sigma(sensor, z)
        self.max_conflict = mapper.scan_conflict
        self._scan = self.DeclareAbstractInputPort("registered_scan", AbstractValue.Make(RegisteredScan()))
        self._state = self.DeclareAbstractState(AbstractValue.Make(_Scans()))
        empty = (np.zeros((0, 3)), np.zeros((0, 3), np.int32))
        self.DeclareAbstractOutputPort("mesh", lambda: AbstractValue.Make(empty), self._calc_mesh,
                                       {self.abstract_state_ticket(self._state)})
        self.DeclareAbstractOutputPort("left_out", lambda: AbstractValue.Make({}), self._calc_left_out,
                                       {self.abstract_state_ticket(self._state)})
        self.DeclareAbstractOutputPort("scans", lambda: AbstractValue.Make(()), self._calc_scans,
                                       {self.abstract_state_ticket(self._state)})
        self.DeclarePeriodicUnrestrictedUpdateEvent(dt, 0.0, self._update)

    def _update(self, context, state):
        mem: _Scans = context.get_abstract_state(self._state).get_value()
        scan: RegisteredScan = self._scan.Eval(context)
        if scan.index <= mem.index:
            return
        scans = mem.scans
        if scan.integrate and len(scan.points):
            with stage(MAP, "surface_fusion"):
                P = np.asarray(scan.points, float)
                P = P[np.all((P >= self._lo) & (P <= self._hi), axis=1)]
                scans = scans + ((np.asarray(scan.pose, float), depth_from_points(P, scan.pose, *self._intr)),)
        state.get_mutable_abstract_state(self._state).set_value(_Scans(scan.index, scans))

    def _consistent(self, context) -> tuple[list, dict]:
        """(the scans that agree, {scan number: conflict share} of those left out), once per state."""
        mem: _Scans = context.get_abstract_state(self._state).get_value()
        have = getattr(mem, "consistent", None)
        if have is None:
            if self.max_conflict >= 1.0:
                have = (list(mem.scans), {})
            else:
                w, h = self._intr[:2]
                step = max(2, int(round(np.sqrt(w * h / 6336.0))))  # about the SR4000's pixels at 2
                kept, left_out = consistent_scans(mem.scans, self._intr, self._sigma, self.max_conflict, step)
                have = ([mem.scans[i] for i in kept], left_out)
            mem.consistent = have
        return have

    def _calc_left_out(self, context, output):
        output.set_value(dict(self._consistent(context)[1]))

    def _calc_scans(self, context, output):
        output.set_value(tuple(context.get_abstract_state(self._state).get_value().scans))

    def _calc_mesh(self, context, output):
        scans = self._consistent(context)[0]
        if not scans:
            output.set_value((np.zeros((0, 3)), np.zeros((0, 3), np.int32)))
            return
        output.set_value(fuse_tsdf(scans, self._intr, self.crop_min, self.crop_max, voxel=self.voxel,
                                   trunc=4 * self.voxel, z_far=self._z_far))
