"""The models of godobject_drake's scenes, installed as package data.

Drake's parser reaches them as ``package://godobject_models/...`` (``package.xml`` names the
package); Python finds the folder with ``importlib.resources.files("godobject_models")``. In a
clone this is the ``models/`` folder (``pyproject.toml`` maps it), so nothing moved when the
project became an installable wheel.
"""
