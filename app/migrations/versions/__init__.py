"""One file per schema revision, oldest first.

``0001_baseline`` adopts the files of the old ``schema_version`` scheme."""
