"""The grasp-quality model: crops -> quality_net (``Network(init, apply)``) -> dataset (D0) ->
pretrain (θ0, core sets, screen) -> artifacts (the shipped package data)."""
