"""Perception: the paper's vehicle detector (section 6, Figure 4).

Stages, each a separate module: ``registration`` (camera motion, Eq. 15),
``background`` (median of aligned previous frames, Eq. 14), ``blobs``
(subtraction, morphology, candidates Q_bc, Eq. 16), and ``frontend``, the object
that runs them frame by frame; ``quality`` scores candidates against truth.
"""

#: Bisection steps of on-demand certification (``verify``, ``campaign --payoffs``): it
#: bounds a handful of detections, so it can afford three times ``perceive --certify``'s 2
#: (docs/cnn.md: median ratio 0.057 -> 0.070).
ON_DEMAND_STEPS = 6

#: Where the networks come from: a ``lesmc train`` directory (``--nets``), the user's N_dr
#: and N_lp files (``--detector``, ``--locator``); None: the shipped ones. ``load_nets(*files)``.
NetFiles = tuple[str | None, str | None, str | None]
