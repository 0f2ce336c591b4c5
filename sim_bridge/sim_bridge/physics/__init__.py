"""Drake physics of the 2F-85 and the objects (paper Sec. III): contact settings,
actuators, the hand, objects, the gravity-free grasp simulation, disturbance rejection,
gravity projection, the tabletop scene and depth rendering. Imports no other sub-package."""
