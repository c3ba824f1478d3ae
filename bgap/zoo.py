# `python -m bgap.<command>` kept for scripts and dvc.yaml; the command is its import.
from bgap.experiments.zoo import main

if __name__ == "__main__":
    main()
