"""Polynomial-landmark EKF SLAM, one instance per robot (numpy/scipy only)."""
