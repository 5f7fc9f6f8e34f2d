"""The simulated world: the robot and its state, the scene and the objects, the sensor model,
the motion and its noise, poses."""
