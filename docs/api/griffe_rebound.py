"""A Griffe extension for the API pages: names a package's ``__init__`` rebinds at run time.

``rift_jax/_solvers/__init__.py`` runs ``from .kaczmarz import kaczmarz``, so at run time
``rift_jax._solvers.kaczmarz`` is the function, not the module of that name. Griffe's static
analysis keeps the module, so ``rift_jax.solvers.kaczmarz`` would be documented as a module
(and, as modules are not listed, not at all). This points each such alias at the object the
import put there. (Importing the package instead, mkdocstrings' ``force_inspection``, gets
this right but gives every attribute the docstring of its value's type.)
"""

import griffe


class RuntimeRebinding(griffe.Extension):
    def on_package(self, *, pkg: griffe.Module, **kwargs) -> None:
        for module in _modules(pkg):
            for alias in module.members.values():
                if not alias.is_alias:
                    continue
                package_path, _, name = alias.target_path.rpartition(".")
                try:
                    package = pkg.modules_collection.get_member(package_path)
                except (KeyError, ValueError):
                    continue
                rebound = f"{alias.target_path}.{name}"  # from .NAME import NAME
                if not package.is_alias and package.is_module:
                    if package.imports.get(name) == rebound:
                        alias.target = pkg.modules_collection.get_member(rebound)


def _modules(module: griffe.Module):
    yield module
    for member in module.members.values():
        if not member.is_alias and member.is_module:
            yield from _modules(member)
