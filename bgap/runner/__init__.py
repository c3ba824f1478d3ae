"""Where and how work runs: this process, a pool of worker processes, or a Ray cluster.

The study's code (training, evaluation, selection, the searches) asks this package to run
its jobs and never knows the backend:

- :mod:`~bgap.runner.jobs`: N jobs here, side by side in processes, or as Ray tasks;
- :mod:`~bgap.runner.pools`: the process pools and the threads each process gets;
- :mod:`~bgap.runner.cluster`: Ray (connecting, tasks, shipping run folders to nodes);
- :mod:`~bgap.runner.locks`: one writer per output folder;
- :mod:`~bgap.runner.interrupt`: Ctrl-C as a flag that long work polls;
- :mod:`~bgap.runner.numerics`: the CPU kernels pinned for the same numbers on any machine.

None of it changes what a job computes. It sits above :mod:`bgap.common` and below the
agents, which need its Ctrl-C flag. Importing it loads neither torch nor Ray.
"""
