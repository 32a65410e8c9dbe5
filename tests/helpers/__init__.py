"""Helpers shared by the tests (import as ``tests.helpers.<module>``).

- :mod:`.surrogates` - tiny untrained surrogates (:func:`~.surrogates.tiny_surrogate`);
- :mod:`.training` - tiny datasets and training configs;
- :mod:`.ingest`, :mod:`.arm3_plant` - logs of an independent 3-joint test arm for the
  import tests (and ``examples/arm3_make_logs.py``).
"""
