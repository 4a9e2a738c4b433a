"""RAFT optical flow (Teed & Deng, ECCV 2020), written here: the network
(:mod:`pipeline.raft.model`), checkpoints and flow of a clip (:mod:`pipeline.raft.estimator`),
procedural training pairs (:mod:`pipeline.raft.pairs`) and CPU training
(:mod:`pipeline.raft.train`, ``python -m pipeline.raft train``)."""
