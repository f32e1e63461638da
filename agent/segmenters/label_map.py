"""Label maps: a model's classes -> calnav's classes, many to one.

A model's label set is rarely calnav's (ADE20K-150 for Segformer, COCO for Mask R-CNN,
NYU40 / ScanNet-20 for RGB-D networks). ``segmenter.label_map`` names a built-in map
(``ade20k``, ``nyu40``, ``scannet20``, ``coco_panoptic``: ``label_maps/<name>.tsv`` beside
this file) or a user file:

- TSV: ``id <TAB> model_class <TAB> calnav_class`` rows after an ``id model_class calnav_class``
  header ('#' comment lines first), the calnav class empty for a class that maps to nothing;
- YAML / JSON: ``{model_class: calnav_class or null, ...}`` in the model's output order.

Each model class is listed once in every format: a key written twice is an error naming it
(YAML and JSON parsers would silently keep the last, so a model's ``wall`` could become
``ceiling``).

Combining: the model's logits become probabilities (softmax over the model's K_m classes), the
probabilities of the model classes mapped to one calnav class are *added* (adding logits would
be a product of probabilities, an "and" where the model says "or"), and the calnav logits are
their logarithms, floored at ``log(PROB_FLOOR)`` so that a calnav class no model class maps to
keeps a finite logit. **Rest bucket**: the probability of model classes that map to nothing
(sky, person, window, ...) is spread evenly over the calnav classes -- "none of these" is no
evidence for any of them -- so each pixel's calnav probabilities still sum to 1 and such pixels
fuse as uninformative observations. A goal category that no model class maps to is an error.

As a matrix: ``P_calnav = P_model @ A`` with ``A`` (K_m, K_c), one 1 per mapped row and
``1 / K_c`` across each rest row; done on the model's device at the model's output resolution.
"""
from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

LABEL_MAP_DIR = Path(__file__).resolve().parent / "label_maps"
BUILTIN_LABEL_MAPS: tuple[str, ...] = ("ade20k", "nyu40", "scannet20", "coco_panoptic")
PROB_FLOOR = 1e-8   # smallest calnav probability: log(1e-8) = -18.4, a finite logit


@dataclass(frozen=True)
class LabelMap:
    """model_classes (K_m names, output-channel order) and, per model class, its calnav class
    or None (the rest bucket)."""

    source: str
    model_classes: tuple[str, ...]
    targets: tuple[str | None, ...]

    def __post_init__(self) -> None:
        if len(self.model_classes) != len(self.targets) or not self.model_classes:
            raise ValueError(f"label map {self.source}: needs one target per model class, got "
                             f"{len(self.model_classes)} classes and {len(self.targets)} targets")
        seen: set[str] = set()
        for name in self.model_classes:
            if name in seen:
                raise ValueError(f"label map {self.source}: model class {name!r} is listed twice")
            seen.add(name)

    def reorder(self, model_classes: tuple[str, ...] | list[str]) -> "LabelMap":
        """The map for a model whose output channels are ``model_classes`` (by name, e.g. a Hugging
        Face model's id2label); model classes the map does not list go to the rest bucket."""
        lookup = dict(zip(self.model_classes, self.targets))
        return LabelMap(self.source, tuple(model_classes), tuple(lookup.get(n) for n in model_classes))


def read_label_map(spec: str) -> LabelMap:
    """The label map ``spec``: a built-in name (BUILTIN_LABEL_MAPS) or a .tsv / .yaml / .json
    file. ValueError / FileNotFoundError name the file, the line and the valid forms."""
    if spec in BUILTIN_LABEL_MAPS:
        return _read_tsv(LABEL_MAP_DIR / f"{spec}.tsv")
    path = Path(spec)
    if not path.is_file():
        raise FileNotFoundError(f"label map {spec!r} is neither a built-in map ({', '.join(BUILTIN_LABEL_MAPS)}) "
                                "nor a file (.tsv, .yaml, .json)")
    if path.suffix.lower() == ".tsv":
        return _read_tsv(path)
    if path.suffix.lower() in (".yaml", ".yml", ".json"):
        return _read_mapping(path)
    raise ValueError(f"label map {path}: unknown format {path.suffix!r}; use .tsv, .yaml or .json")


def _read_tsv(path: Path) -> LabelMap:
    try:
        lines = [ln for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip() and not ln.startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read label map {path}: {exc}") from None
    rows = list(csv.reader(lines, delimiter="\t"))
    if not rows or [c.strip() for c in rows[0]] != ["id", "model_class", "calnav_class"]:
        raise ValueError(f"label map {path}: the first row must be the header 'id<TAB>model_class<TAB>calnav_class'")
    names, targets = [], []
    for i, row in enumerate(rows[1:]):
        if len(row) not in (2, 3) or row[0].strip() != str(i):
            raise ValueError(f"label map {path}: row {i + 1} must be '{i}<TAB>model class<TAB>calnav class "
                             f"(empty = rest)', got {row!r}")
        names.append(row[1].strip())
        targets.append((row[2].strip() if len(row) == 3 else "") or None)
    return LabelMap(str(path), tuple(names), tuple(targets))


class DuplicateClass(ValueError):
    """A model class written twice in a YAML / JSON label map (both parsers would keep the last
    silently: a model's ``wall`` quietly becoming ``ceiling``)."""


def _unique_pairs(pairs: list[tuple[str, object]]) -> dict:
    """``json.loads`` object hook: the object as a dict, DuplicateClass for a key given twice."""
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise DuplicateClass(f"model class {key!r} is listed twice; give each model class one calnav class")
        out[key] = value
    return out


def _unique_key_loader():
    """``common.yaml_keys``' loader raising DuplicateClass (with both lines) for a model class
    written twice. Built on first use (PyYAML is imported only for YAML maps)."""
    from calnav.common.yaml_keys import unique_key_loader

    return unique_key_loader(lambda key, first, line: DuplicateClass(
        f"model class {key!r} is listed twice (lines {first} and {line}); give each model class one calnav class"))


def _read_mapping(path: Path) -> LabelMap:
    import yaml

    try:
        text = path.read_text(encoding="utf-8")
        data = json.loads(text, object_pairs_hook=_unique_pairs) if path.suffix.lower() == ".json" else \
            yaml.load(text, Loader=_unique_key_loader())  # noqa: S506 (a SafeLoader)
    except DuplicateClass as exc:
        raise ValueError(f"label map {path}: {exc}") from None
    except (OSError, UnicodeDecodeError, ValueError, yaml.YAMLError) as exc:
        raise ValueError(f"cannot read label map {path}: {str(exc).splitlines()[0]}") from None
    if not isinstance(data, dict) or not all(isinstance(v, (str, type(None))) for v in data.values()):
        raise ValueError(f"label map {path}: must be a mapping {{model class: calnav class or null}} in the "
                         "model's output order")
    return LabelMap(str(path), tuple(str(k) for k in data), tuple(v or None for v in data.values()))


def mapping_matrix(label_map: LabelMap, calnav_classes: tuple[str, ...],
                   goal_categories: tuple[str, ...] = ()) -> np.ndarray:
    """A (K_m, K_c) float32: row m is one-hot at model class m's calnav class, or 1/K_c for the
    rest bucket. ValueError for a target that is not a calnav class, or a goal category that no
    model class maps to (named)."""
    index = {name: i for i, name in enumerate(calnav_classes)}
    unknown = sorted({t for t in label_map.targets if t is not None and t not in index})
    if unknown:
        raise ValueError(f"label map {label_map.source}: {', '.join(unknown)} not calnav classes; "
                         f"valid: {', '.join(calnav_classes)}")
    mapped = {t for t in label_map.targets if t is not None}
    missing = [g for g in goal_categories if g not in mapped]
    if missing:
        raise ValueError(f"label map {label_map.source}: no model class maps to goal categor"
                         f"{'y' if len(missing) == 1 else 'ies'} {', '.join(missing)}; map one in the label map "
                         "(or use a model that predicts it)")
    a = np.full((len(label_map.targets), len(calnav_classes)), 1.0 / len(calnav_classes), np.float32)
    for m, target in enumerate(label_map.targets):
        if target is not None:
            a[m] = 0.0
            a[m, index[target]] = 1.0
    return a
