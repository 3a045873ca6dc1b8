"""The compiled estimator (numba, ``cache=True``): small fixed-size algebra, the filter bank,
the paper's observer, the sample streams, the monitor, the learners and the observer's
per-sample entry points, each a module of functions over arrays laid out by
:mod:`~mav_observer.core.kernels.layout`. Import through :mod:`mav_observer.core.compiled`,
which loads (or on a machine's first run compiles) them."""
