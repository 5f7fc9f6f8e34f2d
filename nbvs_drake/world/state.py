"""The robot's state and control layout, defined once for the whole package.

State q = [x, y, theta, q1..q5]: the PatrolBot's planar base pose and the Katana 6M180's five
arm joints (m, rad). Control u = [v, w_b, w_1..w_5]: the base's forward and angular velocities
and the arm joints' velocities, each held for the control period (Vasquez-Gomez et al. 2017, §6).
"""

NQ = 8  #: state size [x, y, theta, q1..q5]
NU = 7  #: control size [v, w_b, w_1..w_5]
