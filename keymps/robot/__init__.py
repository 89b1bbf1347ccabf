"""The arm: UR model in Pinocchio (FK, IK), tool descriptions, the independent safety validator."""
