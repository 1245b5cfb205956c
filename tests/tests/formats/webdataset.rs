//! Checks of the webdataset part of issue 10 (filled in by its branch).
