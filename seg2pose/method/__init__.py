"""The Seg2Pose method: default heights, matching masks to truth, mask features, the network
(Seg2PoseNet), sparse inference, checkpoints, the far-residual check and the pipeline
(masks -> world poses)."""
