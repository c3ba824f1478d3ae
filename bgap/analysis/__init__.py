"""The study's statistics and its figures: intervals, tests, claims and the results page."""
