"""Controllers that are not learned, and policy-side helpers for SB3."""
