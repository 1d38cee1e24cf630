"""Data contracts (installed as ``hadal.schemas``): the variable registry of every product (``variables.yaml``,
loaded by :mod:`hadal.products.registry`), the ``sensors`` product schema and the MCAP channel JSON Schemas of
the sample vehicle (``mcap/*.json``, the only copy: ``hadal.synth.writers`` registers them as they are). Read them
with ``importlib.resources.files("hadal.schemas")``."""
