"""One exception base: every error the package raises on purpose is a RegistrationError, and
bad input is still a ValueError for callers that catch that."""

import numpy as np
import pytest

import rbc_registration
from rbc_registration.core.measurements.accumulator import FiducialAccumulator
from rbc_registration.core.errors import InputError, OperationError, RegistrationError
from rbc_registration.core.measurements.records import RejectedMeasurement
from rbc_registration.io.bag.records import BagError
from rbc_registration.io.csv_io import CsvError, read_fiducials
from rbc_registration.pipeline.build_process import BuildCancelled, BuildProcessDied
from rbc_registration.pipeline.files import NotARegularFile, StateDirBusy
from rbc_registration.pipeline.journal_records import JournalMismatch
from rbc_registration.pipeline.offline import EvaluationError


@pytest.mark.parametrize("cls", [CsvError, BagError, RejectedMeasurement, JournalMismatch,
                                 StateDirBusy, NotARegularFile, EvaluationError])
def test_input_errors_have_the_project_base_and_stay_value_errors(cls):
    assert issubclass(cls, InputError) and issubclass(cls, RegistrationError)
    assert issubclass(cls, ValueError)


@pytest.mark.parametrize("cls", [BuildProcessDied, BuildCancelled])
def test_operation_errors_have_the_project_base(cls):
    assert issubclass(cls, OperationError) and issubclass(cls, RuntimeError)
    assert issubclass(cls, RegistrationError)


def test_the_base_is_exported_at_the_package_root():
    assert rbc_registration.RegistrationError is RegistrationError
    assert rbc_registration.InputError is InputError


def test_a_library_caller_catches_a_bad_file_and_a_rejected_measurement(tmp_path):
    bad = tmp_path / "f.csv"
    bad.write_text("id,x,y\nF1,1,nan\n")
    with pytest.raises(RegistrationError, match="f.csv"):
        read_fiducials(str(bad))
    acc = FiducialAccumulator(3, "tracker", "world", merge_radius=0.01)
    with pytest.raises(RegistrationError, match="frame"):
        acc.add("F1", np.zeros(3), np.zeros(3), working_frame="camera")
