"""Robot models: DH robots, non-geometric errors, batched kinematics, serial chains, URDF."""
