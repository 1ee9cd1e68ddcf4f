"""Diagnosis of the station's simulation against measured data (issue 13): name the cause, extend, measure."""

from .arm import ArmDiagnosis, CandidateTest, Step, diagnose_arm

__all__ = ["ArmDiagnosis", "CandidateTest", "Step", "diagnose_arm"]
