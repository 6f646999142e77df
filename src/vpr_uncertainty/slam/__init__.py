"""Pose graphs: files read and written without loss (:mod:`.graph_file`), and the gate's decisions and GTSAM's
optimisation on them (:mod:`.pose_graph`, the ``slam`` extra)."""
