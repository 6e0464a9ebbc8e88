"""Policies that drive the team: scripted ones and learned ones."""
