"""Stand-in for ``forcedimension_core`` (README.md here): only its ``dhd`` module."""
