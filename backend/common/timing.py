"""The names of the pipeline's timed stages (milliseconds in a snapshot's `timing_ms` and in
metrics.json, DESIGN §7). A string enum: a stage prints, compares and serializes as its name,
and a misspelt stage is an error where it is written, not a silent new key."""

from __future__ import annotations

import enum


class Stage(enum.StrEnum):
    LOAD = "load"  # reading or rendering the images (not the pipeline's own time)
    LOAD_WAIT = "load_wait"  # the part of LOAD the pipeline waited for (the rest overlapped with tracking: backend.pipeline.prefetch)
    POINT_DM = "point_dm"  # ORB detection and stereo matching of points (Table III "point D&M")
    TRACKING = "tracking"
    LINE_DM = "line_dm"  # LSD + LBD segments, stereo and map matching ("line D&M")
    MAPPING = "mapping"  # the keyframe's observations and new landmarks
    TRIANGULATION = "triangulation"
    DETECTION = "detection"
    PLANE_SEG = "plane_seg"  # plane-instance segmentation
    PLANE_FIT = "plane_fit"  # the co-planar detection
    SETUP = "setup"  # the window's problem built
    OPTIMIZATION = "optimization"
    LINEARIZE = "linearize"
    SOLVE = "solve"
    UPDATE = "update"  # the solution written back
    HESSIAN = "hessian"
    CULLING = "culling"
    IMAGE = "image"  # the debugger's keyframe image
    TOTAL = "total"
    TOTAL_PER_FRAME = "total_per_frame"


# Timed per frame within a step (averaged per frame); every other stage runs once per keyframe.
PER_FRAME_STAGES: tuple[Stage, ...] = (Stage.POINT_DM, Stage.TRACKING, Stage.LOAD, Stage.LOAD_WAIT)
