"""Data contracts (installed as ``hadal.schemas``): the variable registry of every product (``variables.yaml``,
loaded by :mod:`hadal.products.registry`: the only declaration of each column's units, standard_name and
long_name), the ``sensors`` table contract (``sensors.yaml``: column set, dtypes, time rules) and the MCAP
channel JSON Schemas of the sample vehicle (``mcap/*.json``, the only copy: ``hadal.synth.writers`` registers
them as they are). Read them with ``importlib.resources.files("hadal.schemas")``."""
