//! `stereogen report DATASET`: one self-contained HTML page about a dataset.
