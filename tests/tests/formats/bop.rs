//! Checks of the bop part of issue 10 (filled in by its branch).
