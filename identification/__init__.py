"""System identification for seekopt: seek logs, plant models and estimators (see docs/ARCHITECTURE.md)."""
