"""Two recorded data sets derive fit is checked on, each as a model file and a table of
measurements (and inputs) as derive fit reads them.

- **robot**: pykalman's ``load_robot`` (``pip install pykalman``): 501 noisy 2-D
  observations of a 5-state linear system with its transition matrix, observation matrix,
  per-step transition offsets and observation offset; the free parameters are the scales
  ``sq`` and ``sr`` of its transition and observation covariances (Q = sq Q_robot, R = sr
  R_robot; Q_robot and R_robot symmetrised, their transposes differ in the last
  digits). Step k (0..499) predicts with offset k, an input (B = I), and updates with
  observation k + 1 less the observation offset (a masked one NaN: only observation 0 is
  masked, the one the run does not use); the run starts
  from the data set's initial state mean and covariance.
- **receiver**: gnss-benchmark's moving receiver (derive.apps.gnss.data's data set, its
  reference trajectory at 1 Hz, 1158 epochs; ``pip install gnss-benchmark``), its
  latitude, longitude and height as local east, north and up metres about the first epoch;
  a constant-velocity model on each axis (white acceleration of spectral density q_axis,
  exactly discretised over dt = 1 s) with position measured with variance r_axis: six free
  parameters.
"""

from __future__ import annotations

import json
import math
from functools import cache
from pathlib import Path

import numpy as np

from derive.apps.gnss.data import DATASET, dataset_file

#: WGS-84's semi-major axis (m) and first eccentricity squared.
WGS84_A, WGS84_E2 = 6378137.0, 6.69437999014e-3

REFERENCE_TRAJECTORY = "reference_trajectory.csv"
AXES = ("e", "n", "u")


def _matrix(rows) -> str:
    return "[" + ", ".join("[" + ", ".join(str(v) for v in row) + "]" for row in rows) + "]"


def _scaled(symbol: str, matrix: np.ndarray) -> str:
    return _matrix([[f'"{symbol} * {float(v)!r}"' if v != 0 else 0 for v in row]
                    for row in matrix])


def _symmetric(matrix) -> np.ndarray:
    """The mean of a covariance and its transpose (the data set's differ in the last
    digits)."""
    matrix = np.asarray(matrix, dtype=float)
    return (matrix + matrix.T) / 2


@cache
def _robot():
    from pykalman.datasets import load_robot  # optional: the anchor's data set

    return load_robot()


def robot_model_text() -> str:
    """The robot's model file: its F, H; Q and R scaled by the free sq and sr."""
    d = _robot()
    n = d.transition_matrix.shape[0]
    inputs = [f"b{i}" for i in range(n)]
    return f"""# pykalman's robot data set (load_robot): its matrices, noise scales free.
[model]
name = "robot"
description = "pykalman's robot: 5 states, 2 observations, transition offsets as inputs."
source = "pykalman.datasets.load_robot"
states = {json.dumps([f"s{i}" for i in range(n)])}
measurements = ["o0", "o1"]

[parameters]
sq = {{ description = "scale of the transition covariance", domain = "positive", example = 1 }}
sr = {{ description = "scale of the observation covariance", domain = "positive", example = 1 }}

[discrete]
F = {_matrix(d.transition_matrix.tolist())}
H = {_matrix(d.observation_matrix.tolist())}
Q = {_scaled("sq", _symmetric(d.transition_covariance))}
R = {_scaled("sr", _symmetric(d.observation_covariance))}
inputs = {json.dumps(inputs)}
B = {_matrix(np.eye(n, dtype=int).tolist())}

[initial]
x0 = {json.dumps([float(v) for v in d.initial_state_mean])}
P0 = {_matrix(np.asarray(d.initial_state_covariance, dtype=float).tolist())}
"""


def robot_data() -> np.ndarray:
    """(500, 7): observation k + 1 less the offset (NaN where masked), transition offset k."""
    d = _robot()
    obs = np.ma.filled(np.ma.asarray(d.observations, dtype=float), np.nan)
    return np.column_stack([obs[1:] - d.observation_offset, d.transition_offsets])


def receiver_model_text() -> str:
    """Constant velocity on east, north and up, q and r free per axis."""
    states = [s for a in AXES for s in (f"p{a}", f"v{a}")]
    F = np.kron(np.eye(3, dtype=int), np.array([[1, 1], [0, 1]])).tolist()
    H = [[1 if j == 2 * i else 0 for j in range(6)] for i in range(3)]
    Q = [[0] * 6 for _ in range(6)]
    for i, a in enumerate(AXES):
        Q[2 * i][2 * i], Q[2 * i][2 * i + 1] = f'"q{a}/3"', f'"q{a}/2"'
        Q[2 * i + 1][2 * i], Q[2 * i + 1][2 * i + 1] = f'"q{a}/2"', f'"q{a}"'
    R = [[f'"r{a}"' if i == j else 0 for j in range(3)] for i, a in enumerate(AXES)]
    params = "\n".join(
        [f'q{a} = {{ description = "white acceleration density, {a} (m2/s3)", '
         f'domain = "positive", example = 0.1 }}' for a in AXES]
        + [f'r{a} = {{ description = "position variance, {a} (m2)", domain = "positive", '
           f'example = 0.1 }}' for a in AXES])
    return f"""# gnss-benchmark's moving receiver: constant velocity per axis, q and r free.
[model]
name = "receiver"
description = "Constant velocity on east, north and up (dt = 1 s), position measured."
source = "gnss-benchmark {DATASET} reference trajectory"
states = {json.dumps(states)}
measurements = ["ze", "zn", "zu"]

[parameters]
{params}

[discrete]
F = {_matrix(F)}
H = {_matrix(H)}
Q = {_matrix(Q)}
R = {_matrix(R)}

[initial]
x0 = [0, 0, 0, 0, 0, 0]
P0 = {_matrix((np.eye(6) * 10.0).tolist())}
P0_pattern = "block"
"""


def receiver_file() -> Path:
    """The reference trajectory of the moving receiver (gnss-benchmark's data set)."""
    return dataset_file(REFERENCE_TRAJECTORY)


@cache
def _receiver() -> np.ndarray:
    table = np.loadtxt(receiver_file(), delimiter=",", comments="#")
    lat, lon, h = np.radians(table[:, 2]), np.radians(table[:, 3]), table[:, 4]
    lat0 = lat[0]
    s = math.sin(lat0)
    normal = WGS84_A / math.sqrt(1 - WGS84_E2 * s * s)  # prime vertical radius
    meridian = normal * (1 - WGS84_E2) / (1 - WGS84_E2 * s * s)
    east = (lon - lon[0]) * (normal + h[0]) * math.cos(lat0)
    north = (lat - lat0) * (meridian + h[0])
    return np.column_stack([east, north, h - h[0]])


def receiver_data() -> np.ndarray:
    """(1158, 3): east, north, up (m) about the first epoch."""
    return _receiver().copy()
