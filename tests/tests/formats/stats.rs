//! Checks of the stats part of issue 10 (filled in by its branch).
