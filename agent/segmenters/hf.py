"""``hf``: a Hugging Face ``transformers`` semantic-segmentation model (Segformer, the paper's
RGB model; any ``AutoModelForSemanticSegmentation`` with its image processor).

``segmenter.model``: a local directory written by ``save_pretrained`` (or a hub id on a
machine with a network); ``segmenter.label_map``: its label set -> calnav's (``ade20k`` for
ADE20K-pretrained Segformer). The processor resizes and normalises as the model was trained;
the logits (Segformer: 1/4 of the processor's size) are label-mapped at that resolution and
upsampled to the frame (``agent.segmenters.adapter``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from calnav.agent.segmenters.adapter import ModelAdapter
from calnav.agent.segmenters.base import SegmenterConfig


def _load(model_id: str, key: str = "segmenter"):
    try:
        from transformers import AutoImageProcessor, AutoModelForSemanticSegmentation
        from transformers.utils import logging as hf_logging
    except ImportError:
        raise ValueError("segmenter hf needs transformers: pip install 'calnav[hf]'") from None
    if not model_id:
        raise ValueError(f"segmenter hf needs {key}.model: a save_pretrained directory or a hub id")
    local = Path(model_id).exists()
    if not local and (model_id.startswith(("/", "./", "../", "~")) or model_id.count("/") > 1):
        raise FileNotFoundError(f"{key}.model {model_id} does not exist (a save_pretrained directory, or a hub id "
                                "'org/name' on a machine with a network)")
    if local and not (Path(model_id) / "config.json").is_file():
        raise FileNotFoundError(f"{key}.model {model_id} has no config.json: give a directory written by "
                                "save_pretrained")
    try:
        # quiet in every worker: no weight-loading bar, no note that the PIL backend is used without torchvision
        verbosity, bars = hf_logging.get_verbosity(), hf_logging.is_progress_bar_enabled()
        hf_logging.set_verbosity_error()
        hf_logging.disable_progress_bar()
        try:
            model = AutoModelForSemanticSegmentation.from_pretrained(model_id, local_files_only=local)
            processor = AutoImageProcessor.from_pretrained(model_id, local_files_only=local)
        finally:
            hf_logging.set_verbosity(verbosity)
            if bars:
                hf_logging.enable_progress_bar()
    except (OSError, ValueError, KeyError) as exc:
        where = "the local directory" if local else "the hub (needs a network; or give a save_pretrained directory)"
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ValueError(f"cannot load Hugging Face model {model_id!r} from {where}: {first}") from None
    return model, processor


class HFSegmenter(ModelAdapter):
    """``AutoModelForSemanticSegmentation`` + ``AutoImageProcessor`` from ``cfg.model``."""

    needs_depth = False

    def __init__(self, name: str, cfg: SegmenterConfig, device: str | None, key: str = "segmenter"):
        model, self.processor = _load(cfg.model, key)
        id2label = getattr(model.config, "id2label", None) or {}
        names = tuple(str(id2label[i]) for i in sorted(id2label, key=int)) if id2label else None
        super().__init__(name, cfg, device, names, k_model=getattr(model.config, "num_labels", None), key=key)
        if cfg.threads > 0:
            torch.set_num_threads(cfg.threads)
        self.model = model.eval().to(self.device)

    def model_logits(self, rgb: np.ndarray, depth: np.ndarray | None) -> torch.Tensor:
        inputs = self.processor(images=list(rgb), return_tensors="pt")
        return self.model(pixel_values=inputs["pixel_values"].to(self.device)).logits
