# `python -m bgap.<command>` kept for scripts and dvc.yaml; the command is its import.
from bgap.experiments.watch import main

if __name__ == "__main__":
    main()
