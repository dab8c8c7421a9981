"""The Monte-Carlo engine's keyframe steps (`backend.pipeline.sim_engine.SimEngine`), as
functions and small objects with explicit inputs: its state (`state`: the keyframes'
poses, what each keyframe observed, the landmarks), the simulated keyframe (`measure`:
odometry, noisy observations, instance labels, tracking), triangulation (`triangulate`),
the co-planar detection and association (`planes`) and the window problem (`window`).

World frame z up, metres; pixels of the world's camera; landmark ids are the world's point
and segment indices, keyframe ids the step count."""
