"""One target: the :class:`~common.single_target.runner.Tracker` every mode runs (in-process, in
the tracker service, on offline replay) around a filter of :mod:`common.tracking`, and its
per-frame mechanisms: camera stabilisation (``stabilise``), matching at the target's scale
(``scale``), template adaptation (``adaptation``), loss and re-acquisition (``reacquire``)."""
