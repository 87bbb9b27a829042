"""Perception: the paper's vehicle detector (section 6, Figure 4).

Stages, each a separate module: ``registration`` (camera motion, Eq. 15),
``background`` (median of aligned previous frames, Eq. 14), ``blobs``
(subtraction, morphology, candidates Q_bc, Eq. 16), and ``frontend``, the object
that runs them frame by frame; ``quality`` scores candidates against truth.
"""

import os

#: oneDNN (torch's CPU convolutions) keeps a compiled kernel for every batch shape it has
#: seen, 1,024 by default; DeepFool's shrinking batches bring a new shape at nearly every
#: step, and the cache grew verify's peak by 60 MB. 64 keeps the peak that much lower in
#: the same time (docs/performance.md, "The main job"). Set before torch's first
#: convolution, so any module of lesmc.perception sets it; a value the user set wins.
os.environ.setdefault("ONEDNN_PRIMITIVE_CACHE_CAPACITY", "64")

#: L, the previous frames in the background median (paper section 6.2: "4 or 5"): the
#: front end's default, and what verify, campaign and replay perceive with.
HISTORY = 4

#: delta_bc, the background subtraction's threshold in grey levels (Eq. 16): the front
#: end's default (``BlobConfig``), and what verify perceives a video with.
DELTA_BC = 12

#: The values the front end's settings may take (lesmc/common/fields.py; a scene's
#: ``meta.frontend`` is checked as the scene is read, lesmc/scene/meta_attack.py).
from lesmc.common.fields import FRONTEND_RANGES as FRONTEND_RANGES  # noqa: E402

#: Bisection steps of on-demand certification (``verify``, ``campaign --payoffs``): it
#: bounds a handful of detections, so it can afford three times ``perceive --certify``'s 2
#: (docs/cnn.md: median ratio 0.057 -> 0.070).
ON_DEMAND_STEPS = 6

#: Where the networks come from: a ``lesmc train`` directory (``--nets``), the user's N_dr
#: and N_lp files (``--detector``, ``--locator``); None: the shipped ones. ``load_nets(*files)``.
NetFiles = tuple[str | None, str | None, str | None]
