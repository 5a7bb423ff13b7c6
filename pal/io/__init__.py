"""pal's file formats, in one place.

- :mod:`pal.io.files`: the persistence core: atomic writes, strict JSON, checked ``.npz``
  files with bounded reads, provenance.
- :mod:`pal.io.locks`: the single-writer lock of a directory.
- :mod:`pal.io.dataset` and :mod:`pal.io.dataset_files`: :class:`TransitionDataset` (babbling
  transitions as checksummed ``.npz`` chunks and a JSON manifest) and its on-disk layout.
- :mod:`pal.io.sequence_files`: the RGB-D sequence layout shared by the writers and readers.
- :mod:`pal.io.image_headers`: image dimensions read from file headers, checked before decoding.
- :mod:`pal.io.fuzz`: seeded byte-flip fuzzing of loaders.
"""
