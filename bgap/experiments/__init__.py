"""The commands that train, evaluate and compare policies: train, evaluate, run (the main
job), sweep and recipe (Optuna searches), parity (backend comparison) and bench."""
