"""The medial library: plain functions over arrays (and a queryable field) that the extraction stages adapt."""
