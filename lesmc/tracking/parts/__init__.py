"""Parts a multi-target tracker is composed of (docs/trackers.md), as Stone Soup composes
its trackers: the tracks (:mod:`.tracks`), boxes and IoU (:mod:`.boxes`), the box Kalman
predictor and updater (:mod:`.box_filter`, on lesmc/tracking/kalman.py's functions), the
IoU hypothesiser (:mod:`.hypothesiser`), the global-assignment associator
(:mod:`.associator`), the ``min_hits`` initiator (:mod:`.initiator`) and the ``max_age``
deleter (:mod:`.deleter`); lesmc/tracking/multi.py puts them together (the ``sort``
preset). The point Kalman predictor and updater (:mod:`.point_filter`), the Mahalanobis
hypothesiser with its χ² gate (:mod:`.mahalanobis`), the global nearest neighbour
associator (:mod:`.gnn_associator`) and the M-of-N initiator (:mod:`.m_of_n`), with the
``max_age`` deleter, make the ``gnn`` preset (lesmc/tracking/gnn.py).
"""
