"""Back-end "keyframes" of the online session (`backend.KeyframeBackend`): a robust pose graph
over every robot's keyframes."""
