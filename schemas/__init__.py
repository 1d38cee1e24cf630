"""Data contracts (installed as ``hadal.schemas``): the ``sensors`` product schema and the MCAP channel
JSON Schemas of the sample vehicle. Read them with ``importlib.resources.files("hadal.schemas")``."""
