"""The commands: one module per ``bgap <command>``, each its command line (a Hydra app over
``bgap/conf/<command>.yaml``) and what it prints, over the library's packages.

The top floor: no package imports it. ``bgap <command>``, ``python -m bgap.<command>`` and
``dvc.yaml``'s stages reach a command through its short shim (``bgap/<command>.py``, or a
package's ``__main__.py``), which pins the kernels (:mod:`bgap.runner.numerics`) before this
module loads torch.
"""
