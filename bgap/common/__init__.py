"""Plumbing every stage shares: error types and the one-line command layer, vocabulary,
presets, run folders, Optuna studies, Hydra configuration and plotting set-up."""
