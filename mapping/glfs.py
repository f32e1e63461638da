"""Parameters of the Generalized Learned Fusion Strategy (paper Sec. V-D), theta = (tau, G,
eps, M), with save/load and a class-name check (a table learned for one class list must not be
applied to another).

tau: (K,) per-class temperatures (vector scaling), > 0. g, eps: gates in [0, 1].
M: (K, n_dist, n_angle) >= 0 sample-weight table indexed by predicted class, camera-distance
bin and incidence-angle bin (edges ``distance_edges`` metres, ``angle_edges_deg`` degrees).
Identity parameters (tau = 1, M = 1, G = eps = 0) make GLFS plain naive averaging.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from calnav.common.atomic import write_json_atomic
from calnav.common.npz import check_format_version, load_versioned_npz, save_versioned_npz
from calnav.common.weights import resolve_repo_path
from calnav.mapping.weighting import ANGLE_EDGES_DEG, DISTANCE_EDGES_M

FORMAT_VERSION = 1


@dataclass
class GLFSParams:
    tau: np.ndarray
    g: float
    eps: float
    M: np.ndarray
    distance_edges: tuple[float, ...] = DISTANCE_EDGES_M
    angle_edges_deg: tuple[float, ...] = ANGLE_EDGES_DEG
    class_names: tuple[str, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        self.tau = np.asarray(self.tau, dtype=np.float32).reshape(-1)
        self.M = np.asarray(self.M, dtype=np.float32)
        self.g, self.eps = float(self.g), float(self.eps)
        self.distance_edges = tuple(float(e) for e in self.distance_edges)
        self.angle_edges_deg = tuple(float(e) for e in self.angle_edges_deg)
        if isinstance(self.class_names, (str, bytes)):   # tuple("wall") would be the classes w, a, l, l
            raise ValueError(f"GLFS class_names must be a list of class names, got the string {self.class_names!r}")
        self.class_names = tuple(str(n) for n in self.class_names)
        twice = sorted({n for n in self.class_names if self.class_names.count(n) > 1})
        if twice:
            raise ValueError(f"GLFS class_names lists {', '.join(map(repr, twice))} more than once")
        self.validate()

    @property
    def num_classes(self) -> int:
        return len(self.tau)

    @classmethod
    def identity(cls, num_classes: int, class_names: tuple[str, ...] = (), g: float = 0.0, eps: float = 0.0,
                 distance_edges: tuple[float, ...] = DISTANCE_EDGES_M,
                 angle_edges_deg: tuple[float, ...] = ANGLE_EDGES_DEG) -> "GLFSParams":
        """tau = 1, M = 1 (the initialisation of training); gates as given (default averaging)."""
        shape = (num_classes, len(distance_edges) - 1, len(angle_edges_deg) - 1)
        return cls(np.ones(num_classes), g, eps, np.ones(shape), distance_edges, angle_edges_deg, class_names)

    def validate(self) -> None:
        k = self.num_classes
        if k < 2:
            raise ValueError(f"GLFS tau must hold one temperature per class (K >= 2), got {k}")
        if not np.isfinite(self.tau).all() or (self.tau <= 0).any():
            raise ValueError("GLFS tau must be finite and > 0")
        for name, v in (("g", self.g), ("eps", self.eps)):
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"GLFS gate {name} must be in [0, 1], got {v}")
        for name, edges in (("distance_edges", self.distance_edges), ("angle_edges_deg", self.angle_edges_deg)):
            if len(edges) < 2 or edges[0] != 0.0 or any(b <= a for a, b in zip(edges, edges[1:])):
                raise ValueError(f"GLFS {name} must be >= 2 strictly increasing values starting at 0, got {edges}")
        shape = (k, len(self.distance_edges) - 1, len(self.angle_edges_deg) - 1)
        if self.M.shape != shape:
            raise ValueError(f"GLFS M must have shape (K, n_dist, n_angle) = {shape}, got {self.M.shape}")
        if not np.isfinite(self.M).all() or (self.M < 0).any():
            raise ValueError("GLFS M must be finite and >= 0")
        if self.class_names and len(self.class_names) != k:
            raise ValueError(f"GLFS params name {len(self.class_names)} classes but tau has {k}")

    def check_classes(self, class_names) -> None:
        """Raise if these parameters were made for another class list than ``class_names``."""
        names = tuple(class_names)
        if len(names) != self.num_classes:
            raise ValueError(f"GLFS params are for {self.num_classes} classes, the map has {len(names)}")
        if self.class_names and names != self.class_names:
            diff = [(i, a, b) for i, (a, b) in enumerate(zip(self.class_names, names)) if a != b][:3]
            raise ValueError(f"GLFS params were made for other classes: (index, params, map) {diff}")

    def torch_tensors(self, device: torch.device | str = "cpu") -> dict[str, torch.Tensor]:
        """tau (K,), g (), eps (), M (K, n_dist, n_angle) as float32 tensors."""
        f = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float32), device=device)  # noqa: E731
        return {"tau": f(self.tau), "g": f(self.g), "eps": f(self.eps), "M": f(self.M)}

    # ------------------------------------------------------------------- file io
    def to_dict(self) -> dict:
        return {"format_version": FORMAT_VERSION, "tau": self.tau.tolist(), "g": self.g, "eps": self.eps,
                "M": self.M.tolist(), "distance_edges": list(self.distance_edges),
                "angle_edges_deg": list(self.angle_edges_deg), "class_names": list(self.class_names)}

    def save(self, path: str | os.PathLike) -> Path:
        """Write ``.json`` (readable) or ``.npz``; the suffix decides."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        d = self.to_dict()
        if path.suffix == ".json":
            write_json_atomic(path, d, indent=1)
        elif path.suffix == ".npz":
            meta = {k: v for k, v in d.items() if k not in ("format_version", "tau", "M")}
            save_versioned_npz(path, {"tau": self.tau, "M": self.M}, meta, FORMAT_VERSION)
        else:
            raise ValueError(f"GLFS params file must end in .json or .npz, got {path}")
        return path

    @classmethod
    def load(cls, path: str | os.PathLike, class_names=None) -> "GLFSParams":
        """Read and validate a params file; a relative path that does not exist from the working
        directory is also looked up from the repository root (so configs can name shipped files
        such as ``agent/weights/glfs_learned_rgb.json``). With ``class_names``, the parameters
        must be for exactly those classes. Every error is a ValueError naming the file."""
        path = resolve_repo_path(path)
        if not path.is_file():
            raise ValueError(f"GLFS params file not found: {path}" + (" (a directory)" if path.is_dir() else ""))
        if path.suffix == ".npz":
            arrays, d = load_versioned_npz(path, FORMAT_VERSION, what="GLFS params file")
            d.update(arrays)
        else:
            try:
                d = json.loads(path.read_text())
            except Exception as exc:  # json errors all mean the same to the user
                raise ValueError(f"corrupt GLFS params file {path}: {exc}") from exc
            if not isinstance(d, dict):
                raise ValueError(f"corrupt GLFS params file {path}: expected a JSON object, got {type(d).__name__}")
            check_format_version(d, FORMAT_VERSION, path, what="GLFS params file")
        try:
            params = cls(tau=np.asarray(d["tau"]), g=d["g"], eps=d["eps"], M=np.asarray(d["M"]),
                         distance_edges=tuple(d["distance_edges"]), angle_edges_deg=tuple(d["angle_edges_deg"]),
                         class_names=tuple(d["class_names"]))
            if class_names is not None:
                params.check_classes(class_names)
        except KeyError as exc:
            raise ValueError(f"corrupt GLFS params file {path}: missing {exc}") from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f"GLFS params file {path}: {exc}") from None
        return params
