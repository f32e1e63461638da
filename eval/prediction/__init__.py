"""PEANUT's target prediction: ``collect-maps`` (training maps), ``train-predictor``."""
