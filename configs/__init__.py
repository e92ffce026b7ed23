"""The shipped hyperparameter and gait YAML files (package data snake_env.configs)."""
