"""RSTrace for Blender: the add-on / extension package (glue only).

The renderer is the ``rstrace_engine`` package (numpy + numba, no Blender imports); this
package turns Blender data into its calls and its frames back into render passes.

Module layers, lower never importing higher:
``runtime`` (numba set-up) < ``properties`` < ``materials`` < ``export`` < ``session`` <
``engine`` < ``ui``; ``operators`` (the kernel-cache warm-up) imports ``runtime`` only.

``runtime.configure`` runs before anything imports ``rstrace_engine`` kernels, so numba
caches them in the extension's user directory. Used as a plain package (scripts, tests)::

    import addon
    addon.register()
"""

from . import runtime

runtime.configure(__package__)

from . import engine, export, operators, properties, session, ui  # noqa: E402  (after numba)

__all__ = ["engine", "export", "operators", "properties", "register", "runtime", "session",
           "ui", "unregister"]

#: Registered in this order, unregistered in reverse.
_MODULES = (properties, session, engine, operators, ui)


def register() -> None:
    for module in _MODULES:
        module.register()


def unregister() -> None:
    for module in reversed(_MODULES):
        module.unregister()
