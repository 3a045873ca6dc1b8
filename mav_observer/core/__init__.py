"""The core: the observer and its estimators, pure maths (no I/O, no clock).

:class:`~mav_observer.core.observer.BiasObserver` (Python) drives the compiled kernels of
:mod:`mav_observer.core.kernels` (numba), which hold the state in arrays; the settings are
:mod:`~mav_observer.core.config`, the records :mod:`~mav_observer.core.samples`.
"""
