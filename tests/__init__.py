"""The test suite, a package mirroring ``src/excavator_surrogate`` (shared helpers: ``tests.helpers``)."""
