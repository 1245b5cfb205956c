//! Checks of the eval part of issue 10 (filled in by its branch).
