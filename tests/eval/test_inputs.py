"""eval.inputs: every file a plugged-in segmenter or the predictor loads is fingerprinted in
inputs.json, so a resumed run refuses a model replaced in place like it refuses changed weights."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from calnav.eval.results_dir import ResultsDir, ResultsError

REPO_ROOT = Path(__file__).resolve().parents[2]


def _hf_dir(root: Path) -> Path:
    """What save_pretrained writes (the bytes do not matter to the fingerprint)."""
    root.mkdir()
    (root / "config.json").write_text('{"model_type": "segformer"}')
    (root / "preprocessor_config.json").write_text("{}")
    (root / "model.safetensors").write_bytes(b"weights-1")
    (root / ".cache").mkdir()
    (root / ".cache" / "download.lock").write_text("not read by from_pretrained")
    return root


def test_a_model_directory_replaced_in_place_is_another_run(tmp_path):
    """inputs.json of an hf run lists the model directory's files and the built-in label map; a
    weight file rewritten, added or removed in place is refused on resume, naming the key and
    the directory; hidden files (download caches) are not inputs."""
    from calnav.eval.config import load_config

    model = _hf_dir(tmp_path / "segformer")
    cfg = load_config(None, ["agent.segmenter=hf", f"segmenter.model={model}",
                             "segmenter.label_map=ade20k"])
    out = tmp_path / "run"
    with ResultsDir(out, cfg):
        pass
    saved = json.loads((out / "inputs.json").read_text())
    entry = saved["segmenter.model"]
    assert entry["path"] == str(model)
    assert sorted(entry["files"]) == ["config.json", "model.safetensors", "preprocessor_config.json"]
    assert saved["segmenter.label_map"]["path"].endswith("label_maps/ade20k.tsv")
    (model / ".cache" / "download.lock").write_text("touched")
    (model / "checkpoint-500").mkdir()
    (model / "checkpoint-500" / "model.safetensors").write_bytes(b"a trainer's checkpoint")
    with ResultsDir(out, cfg):
        pass   # hidden files and subfolders (checkpoints, logs) are not what the loader reads: resumes
    refusal = rf"holds results made with other input files: segmenter.model \({model}\) changed since"
    for change in (lambda: (model / "model.safetensors").write_bytes(b"weights-2"),
                   lambda: (model / "pytorch_model.bin").write_bytes(b"weights-1"),
                   lambda: (model / "model.safetensors").unlink()):
        change()
        with pytest.raises(ResultsError, match=refusal):
            ResultsDir(out, cfg).open()
        with ResultsDir(out, cfg, force=True):
            pass   # --force: the new model's run


def test_file_keys_are_inputs_whatever_their_spelling(tmp_path, monkeypatch):
    """Values of the keys that always name a file (predictor weights, an onnx model, segmenter
    weights) are fingerprinted even without a suffix or a directory part; other strings still
    need to look like paths."""
    from calnav.eval.config import load_config, to_dict
    from calnav.eval.inputs import input_fingerprints

    monkeypatch.chdir(tmp_path)
    for name in ("pred", "net", "val"):
        Path(name).write_bytes(name.encode())
    cfg = to_dict(load_config(None, ["agent.segmenter=onnx", "segmenter.model=net",
                                     "agent.exploration=prediction", "agent.predictor_weights=pred"]))
    found = input_fingerprints(cfg)
    assert found["agent.predictor_weights"]["path"] == "pred"
    assert found["segmenter.model"]["path"] == "net"
    assert not any(entry["path"] == "val" for entry in found.values())
