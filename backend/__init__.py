"""The SLAM system: geometry, optimization, evaluation. Imports no viser and no app."""
