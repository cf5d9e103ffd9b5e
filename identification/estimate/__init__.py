"""Plant identification from seek logs.

:func:`identify` (dispatcher, :mod:`.identify`) runs the paper's method (:mod:`.paper`) or the robust
one (:mod:`.robust`) with their settings (:mod:`.settings`) and returns an :class:`Identification`
(:mod:`.result`).  The building blocks: LS Prony and the damped-mode model (:mod:`.prony`), the pooled
matrix pencil (:mod:`.pencil`), the rigid body (:mod:`.rigid`: eq. (8), ZOH rigid response), modal
gains (:mod:`.gains`: eqs. (9)-(11) on the one discretisation), variable projection and noise model
(:mod:`.varpro`), held-out prediction (:mod:`.heldout`), shared least squares, covariance and the
per-seek projector (:mod:`.linalg`), paper-style figures (:mod:`.figures`).
"""
