"""Back-end "robots" of the online session (`backend.RobotsBackend`): one rigid frame per robot."""
