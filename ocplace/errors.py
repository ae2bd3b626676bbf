"""Typed errors. Each message says what went wrong and what the user can do about it."""


class OcplaceError(Exception):
    """Base class of every error ocplace raises on purpose."""

    flag = "failed"  # what a placement that failed with it says among its flags (`models.policy.Placement.flags`)


class MissingAssetPackage(OcplaceError):
    """An object source package is not installed."""


class UnknownObject(OcplaceError, KeyError):
    """An object name that is not in the library."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class AssetBuildError(OcplaceError):
    """An object could not be processed into the library."""


class CatalogueError(AssetBuildError):
    """A user's object catalogue is invalid, or not built as it now reads."""


class LibraryNotBuilt(OcplaceError):
    """The object library cache is missing or incomplete."""


class SceneError(OcplaceError):
    """A scene could not be built, settled or rendered."""


class ObjectsFellOff(SceneError):
    """A drop ended with an object off the table."""


class ParseError(OcplaceError, ValueError):
    """An instruction that cannot be turned into `<reference, relation>` tuples."""

    flag = "parse_failed"


class InvalidPlacementProblem(OcplaceError, ValueError):
    """Grounded tuples or scene geometry that cannot describe a placement problem."""

    flag = "invalid_problem"


class NoFeasiblePlacement(OcplaceError):
    """No placement satisfies every tuple and avoids every object; names the scene and the cause."""

    flag = "empty_region"

    def __init__(self, scene: str, reason: str):
        super().__init__(scene, reason)
        self.scene = scene
        self.reason = reason

    def __str__(self) -> str:
        return (
            f"no feasible placement in scene {self.scene}: {self.reason}. Check the grounded references "
            "and relations; a smaller held object or a finer grid may also help"
        )


class DatasetConfigError(OcplaceError):
    """A dataset configuration that cannot be generated (unknown split or level, zero scenes, ...)."""


class DatasetError(OcplaceError):
    """A dataset folder that is missing, belongs to another dataset, or holds corrupt files."""


class BackboneError(OcplaceError):
    """A backbone spec, checkpoint or input that the backbone cannot use."""


class BackboneUnavailable(BackboneError):
    """A backbone checkpoint that is neither local nor downloadable (for example: no network)."""


class WeightsError(OcplaceError):
    """A weight file that cannot be read safely or does not fit the model (unsafe pickle, bad layout)."""


class FeaturesError(OcplaceError):
    """A feature file that is missing, corrupt, or does not match the data or backbone asked for."""


class EncoderUnavailable(OcplaceError):
    """The sentence encoder's weights are not installed."""


class PolicyFolderError(OcplaceError):
    """A policy folder (`ocplace export`) that cannot be loaded: missing, tampered, of another format or version."""


class TrainingError(OcplaceError):
    """A training run that cannot start or resume (bad configuration, mismatched checkpoint)."""


class PolicyInputError(OcplaceError, ValueError):
    """Input the placement policy cannot use: mismatched image sizes, bad boxes, a bad camera."""


class NoObjectBoxes(PolicyInputError):
    """The image has no object box, but the instruction refers to an object."""

    flag = "no_boxes_for_reference"


class GroundingUncertain(OcplaceError):
    """A reference phrase whose best visual token is below the policy's confidence threshold."""

    flag = "low_confidence"

    def __init__(self, phrase: str, candidates: list[tuple[str, float]], threshold: float):
        super().__init__(phrase, candidates, threshold)
        self.phrase, self.candidates, self.threshold = phrase, candidates, threshold

    def __str__(self) -> str:
        best = ", ".join(f"{label} p={probability:.2f}" for label, probability in self.candidates)
        return (
            f"cannot ground {self.phrase!r} confidently (best candidates: {best}; threshold "
            f"{self.threshold:.2f}); the object may not be in the image or not have a box. Rephrase the "
            "instruction, check the detector's boxes, or lower the threshold (--threshold)"
        )


class LLMConfigError(OcplaceError, ValueError):
    """An LLM parser setting that cannot work (a base URL that is not http(s), a limit <= 0)."""


class LLMUnreachable(OcplaceError):
    """An LLM endpoint that failed in transport (no connection, timeouts, 5xx) for several requests in a row."""


class OutputError(OcplaceError):
    """An output that cannot be written: a path under a file, a read-only folder, a full disk."""


class EvaluationError(OcplaceError):
    """An evaluation that cannot start: unknown method or subset, a missing run directory, bad settings."""


class ResultsError(EvaluationError):
    """A results file that is missing, corrupt, of another schema, or cannot be re-run or summarised."""


class ConfigError(OcplaceError, ValueError):
    """A configuration override that names no setting or gives a value its setting cannot take."""


class UnknownExperiment(OcplaceError, ValueError):
    """An experiment name that `ocplace.configs` does not hold."""


class ClusterError(OcplaceError):
    """A Ray cluster that cannot be started or reached, or that lost a task for good."""


class CacheError(OcplaceError):
    """A folder or file of the cache is not what ocplace made it (a symbolic link where ocplace deletes or creates)."""


class CorpusError(OcplaceError):
    """The pretraining corpus (furniture catalogues) is missing, unreadable or left nothing usable."""


class PlaceEnvError(OcplaceError):
    """A call the placement environment (`ocplace.sim.env`) cannot serve: a step before reset or after the end."""


class InvalidAction(PlaceEnvError, ValueError):
    """An action that is not one table-frame placement `(x, y)`: the wrong shape, or not numbers."""


# Internal conditions, not user errors (no `OcplaceError`): each is caught near where it is raised, or reported as
# one scene's failure.
class FileRefused(OcplaceError, ValueError):
    """A file that cannot be read safely: not a regular file, larger than its kind allows, or JSON nested too deep."""


class MshFormatError(ValueError):
    """The bytes are not a well-formed legacy `.msh` file."""


class UnsolvableScene(RuntimeError):
    """No solvable instruction was found within the configured attempts."""


class SceneTimeout(TimeoutError):
    """A policy past its time on a scene (`--scene-timeout`): that scene fails, the evaluation goes on."""


class PolicyProcessEnded(RuntimeError):
    """The policy's process ended while it had a scene: that scene fails, the next one starts a new process."""


# What anyone's policy (`ocplace evaluate --policy`) may raise without ending the evaluation: any exception,
# and a `sys.exit` too; Ctrl-C (KeyboardInterrupt) still stops it.
POLICY_ERRORS = (Exception, SystemExit)


class PolicyRaised(Exception):
    """What a policy raised in its own process, carried as its text (`TypeName: message`)."""
