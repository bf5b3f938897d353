"""The error every check of user input raises (scene elements and render settings alike)."""


class SceneError(ValueError):
    """Invalid scene input. The message names the offending object or setting."""
