"""The g2o peer of benchmarks/bench_peer.py: ORB-SLAM's back end on the study's problems.

g2o through its Python bindings (`g2opy`, pinned in the test extra), set up as ORB-SLAM2
sets up its bundle adjustment: one `VertexSE3Expmap` per camera (its estimate is the
world-to-camera transform, updated on the left by the exponential map), one
`VertexPointXYZ` per point landmark in the world frame, marginalized (the Schur complement
onto the cameras), an `EdgeSE3ProjectXYZ` for every point observation (the anchor views
included, as for gtsam's 3-DoF points), `BlockSolverSE3` over `LinearSolverEigenSE3`
(Eigen's sparse Cholesky with AMD ordering), and Gauss-Newton or Levenberg-Marquardt.

The gauge as ORB-SLAM fixes it: the first camera is a fixed vertex at the pose prior's
pose (our prior and gtsam's hold it to 10⁻⁶; fixing it is the same in that limit). The
odometry is g2o's `EdgeSE3Expmap` (its relative-pose error is the logarithm in another
frame than ours and gtsam's, so its cost differs slightly away from the measurement; the
cost check prints by how much; in this g2o version its Jacobian is numeric). g2o has no range
edge: the distance prior is a Python `VariableVectorXEdge` with g2o's numeric Jacobian,
one edge, whose cost per iteration `python_edge_ms` reports (it is left in the timings).

Every function here is used by bench_peer.py and its test; nothing is timed here.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import g2opy
import numpy as np

from backend.optim.problem import ProblemData

Algorithm = Literal["gn", "lm"]


class DistanceEdge(g2opy.VariableVectorXEdge):
    """`|c_i − c_j| − d` (m): the distance between the centres of two cameras whose
    vertices hold world-to-camera transforms; g2o differentiates it numerically."""

    def __init__(self, distance: float) -> None:
        super().__init__()
        self.set_dimension(1)
        self.resize(2)
        self.distance = float(distance)

    def compute_error(self) -> None:
        c_i = self.vertex(0).estimate().inverse().translation()
        c_j = self.vertex(1).estimate().inverse().translation()
        self.error = np.array([np.linalg.norm(c_i - c_j) - self.distance])


@dataclasses.dataclass
class G2oGraph:
    """The optimizer with its vertices and edges. `edges` by factor type ("points",
    "anchors", "odometry", "distance_prior"; the pose prior is the fixed first camera)."""

    optimizer: g2opy.SparseOptimizer
    poses: list[g2opy.VertexSE3Expmap]
    points: list[g2opy.VertexPointXYZ]
    edges: dict[str, list[g2opy.OptimizableGraph.Edge]]

    def set_state(self, R_world_camera: np.ndarray, t_world_camera: np.ndarray, p_world: np.ndarray) -> None:
        """Camera-to-world poses (N, 3, 3) / (N, 3) and world points (P, 3), metres."""
        for vertex, R, t in zip(self.poses, R_world_camera, t_world_camera):
            vertex.set_estimate(g2opy.SE3Quat(R.T, -R.T @ t))
        for vertex, X_w in zip(self.points, p_world):
            vertex.set_estimate(np.asarray(X_w, dtype=float))

    def costs(self) -> dict[str, float]:
        """`Σ ½ eᵀΩe` per factor type at the current estimates."""
        out = {}
        for name, edges in self.edges.items():
            total = 0.0
            for edge in edges:
                edge.compute_error()
                total += 0.5 * edge.chi2()
            out[name] = total
        return out

    def positions(self) -> np.ndarray:
        """Camera centres (N, 3) in the world frame, metres."""
        return np.array([v.estimate().inverse().translation() for v in self.poses])

    def total_cost(self) -> float:
        """`Σ ½ eᵀΩe` over every edge at the current estimates."""
        return float(sum(self.costs().values()))


def build_g2o_graph(data: ProblemData, *, points_world: np.ndarray, algorithm: Algorithm) -> G2oGraph:
    """ORB-SLAM2's bundle-adjustment graph of `data` (module docstring) at our initial
    poses, the points at `points_world` (P, 3, metres), except the first camera, which is
    fixed at the pose prior."""
    cam = data.camera
    if np.any(data.point_obs.offset != 0):
        raise ValueError("stereo (right image) observations are not supported by the g2o graph")
    block = g2opy.BlockSolverSE3(g2opy.LinearSolverEigenSE3())
    optimizer = g2opy.SparseOptimizer()
    optimizer.set_algorithm(g2opy.OptimizationAlgorithmGaussNewton(block) if algorithm == "gn" else g2opy.OptimizationAlgorithmLevenberg(block))

    n_poses = len(data.poses.t_world_camera)
    poses = []
    for i in range(n_poses):
        vertex = g2opy.VertexSE3Expmap()
        vertex.set_id(i)
        optimizer.add_vertex(vertex)
        poses.append(vertex)
    points = []
    for p in range(len(data.point_anchor)):
        vertex = g2opy.VertexPointXYZ()
        vertex.set_id(n_poses + p)
        vertex.set_marginalized(True)
        optimizer.add_vertex(vertex)
        points.append(vertex)
    graph = G2oGraph(optimizer, poses, points, {"points": [], "anchors": [], "odometry": [], "distance_prior": []})
    graph.set_state(data.poses.R_world_camera, data.poses.t_world_camera, points_world)

    pr = data.prior
    if pr is None or list(pr.index) != [0]:
        raise ValueError("the g2o graph fixes the first camera: the problem must have a pose prior on camera 0 only")
    poses[0].set_estimate(g2opy.SE3Quat(pr.R_world_camera[0].T, -pr.R_world_camera[0].T @ pr.t_world_camera[0]))
    poses[0].set_fixed(True)

    obs = data.point_obs
    is_anchor = (obs.pose == data.point_anchor[obs.landmark]) & np.all(obs.offset == 0, axis=1)
    information = np.eye(2) / data.sigma_px**2
    for m in range(len(obs)):
        edge = g2opy.EdgeSE3ProjectXYZ()
        edge.set_vertex(0, points[int(obs.landmark[m])])
        edge.set_vertex(1, poses[int(obs.pose[m])])
        edge.set_measurement(np.asarray(obs.uv[m], dtype=float))
        edge.set_information(information)
        edge.fx, edge.fy, edge.cx, edge.cy = cam.fx, cam.fy, cam.cx, cam.cy
        optimizer.add_edge(edge)
        graph.edges["anchors" if is_anchor[m] else "points"].append(edge)

    od = data.odometry
    if od is not None:
        # SE3Quat's tangent order is (rotation, translation), as gtsam's.
        information = np.diag(np.r_[np.full(3, od.sigma_rot**-2), np.full(3, od.sigma_pos**-2)])
        for i, j, R_ij, t_ij in zip(od.i, od.j, od.R_i_j, od.t_i_j):
            edge = g2opy.EdgeSE3Expmap()
            edge.set_vertex(0, poses[int(i)])
            edge.set_vertex(1, poses[int(j)])
            # g2o's error vanishes for the measurement T_j_i = T_j_world · T_world_i.
            edge.set_measurement(g2opy.SE3Quat(R_ij.T, -R_ij.T @ t_ij))
            edge.set_information(information)
            optimizer.add_edge(edge)
            graph.edges["odometry"].append(edge)
    dp = data.distance_prior
    if dp is not None:
        for i, j, dist in zip(dp.i, dp.j, dp.distance):
            edge = DistanceEdge(float(dist))
            edge.set_vertex(0, poses[int(i)])
            edge.set_vertex(1, poses[int(j)])
            edge.set_measurement(np.zeros(1))
            edge.set_information(np.eye(1) / dp.sigma**2)
            optimizer.add_edge(edge)
            graph.edges["distance_prior"].append(edge)
    return graph
