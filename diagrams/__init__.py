"""The shipped scenes: a scenario file (``NAME.yaml``) and a script with its wiring (``NAME.py``).

Installed as the package ``godobject_scenarios`` (``pyproject.toml`` maps this folder), so
``godobject run lego`` finds ``lego.yaml`` with ``importlib.resources`` from any folder.
"""
