"""The robot assets: the catalogue of arms and end-effectors, their conversion from the published CAD/MJCF
into URDFs (`python -m syneepose assets`), forward kinematics, and the end-effectors' BOP models."""
