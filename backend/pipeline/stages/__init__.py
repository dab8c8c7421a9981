"""The keyframe stages every image engine runs in the same way, as functions of the map
with typed inputs and outputs: plane segmentation and co-planar detection (`planes`), the
window solve (`solve`), culling and the local map (`culling`), and the snapshot
(`snapshot`). The engines differ in their front ends (stereo matching, or flow, IMU
prediction and the visual-inertial initialization) and plug what their windows add (the
inertial part, marginalization) into the solve through `solve.WindowExtension`."""
