"""`stillcap demo`: render a synthetic capture and analyse it."""


def demo():
    """Render a synthetic capture and analyse it (placeholder until the studio lands)."""
    raise NotImplementedError
