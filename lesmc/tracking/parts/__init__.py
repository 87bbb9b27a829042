"""Parts the trackers are composed of (docs/trackers.md, "Parts"), as Stone Soup composes
its trackers: hypothesisers (:mod:`.hypothesiser`: the gate, IoU), data associators
(:mod:`.associator`: nearest neighbour, ordered greedy by likelihood, global assignment),
initiators (:mod:`.initiator`: births near the target, ``min_hits``), deleters
(:mod:`.deleter`: the trace limit, pruning, ``max_age``), the attacker's options
(:mod:`.attacker`, every tracker's), the box Kalman predictor and updater
(:mod:`.box_filter`, on lesmc/tracking/kalman.py's functions), tracks and boxes
(:mod:`.tracks`, :mod:`.boxes`), and the states of the joint and multi-target designs
(:mod:`.joint_states`, :mod:`.joint_digest`, :mod:`.joint_step`, :mod:`.states`).
lesmc/tracking/single.py, lesmc/tracking/joint.py and lesmc/tracking/multi.py (the
``sort`` preset) put them together. The point Kalman predictor and updater
(:mod:`.point_filter`), the Mahalanobis hypothesiser with its χ² gate
(:mod:`.mahalanobis`), the global nearest neighbour associator (:mod:`.gnn_associator`)
and the M-of-N initiator (:mod:`.m_of_n`), with the ``max_age`` deleter, make the ``gnn``
preset (lesmc/tracking/gnn.py).
"""
