"""The *Tactile stimulus* Builder component: a shape felt on a vtexp tactile array.

Builder shows it under Stimuli. What it writes into the compiled script calls
:mod:`vtexp.builder` (the runtime; see its docstring):

- before the first routine: the array fetched from PsychoPy's device manager or added
  to it, opened and checked once per experiment (``TactileArray.open``), its close put
  on the script's ``runAtExit`` list (the end of the experiment and Escape), and every
  stimulus of the conditions files of the loops around the routine compiled and checked
  against the device profile's safety limits (``TactileStimulus.prepare_rows``);
- at each routine's start: this trial's stimulus (``start_routine``);
- each frame: the play started at the component's start (on the screen's flip when
  *Sync with screen* is ticked), stopped at its stop, finished when the device has
  played it;
- at the routine's end: the play stopped if it still runs, and the device-reported onset
  of every pulse, on PsychoPy's clock, into the data file (``NAME.onsets`` ...).
"""

from __future__ import annotations

from pathlib import Path

from psychopy.experiment.components import BaseComponent, Param, getInitVals
from psychopy.localization import _translate

#: the stimulus parameters, in the order the runtime takes them
SPEC_PARAMS = {"stimulus": "stimulus", "pipeline": "pipeline", "coding": "coding",
               "encodingParams": "encoding_params", "codingParams": "coding_params"}
PIPELINES = ["edge-trace", "height-contours", "snake-corners", "spiral-path", "covered-cells"]


class TactileStimulusComponent(BaseComponent):
    """A stimulus felt on a vtexp tactile array (vibration motors or SMA pins)."""

    categories = ["Stimuli", "I/O"]
    targets = ["PsychoPy"]
    version = "2026.2.0"
    iconFile = Path(__file__).parent / "tactile.png"
    tooltip = _translate("Tactile stimulus: a shape felt on a vtexp tactile array")
    plugin = "psychopy-vtexp"

    def __init__(self, exp, parentName, name="tactile",
                 startType="time (s)", startVal=0.0, stopType="duration (s)", stopVal="",
                 startEstim="", durationEstim="",
                 device="sim", profile="vest_6x8", deviceLabel="tactileArray",
                 stimulus="shape:shape=square", pipeline="edge-trace", coding="",
                 encodingParams="", codingParams="", syncScreenRefresh=True):
        super().__init__(exp, parentName, name=name, startType=startType, startVal=startVal,
                         stopType=stopType, stopVal=stopVal, startEstim=startEstim,
                         durationEstim=durationEstim, syncScreenRefresh=syncScreenRefresh)
        self.type = "TactileStimulus"
        self.url = None         # no page online yet: Builder shows no Help button
        self.exp.requireImport(importName="builder", importFrom="vtexp", importAs="vtexp_builder")
        self.order += ["stimulus", "pipeline", "coding", "encodingParams", "codingParams",
                       "device", "profile", "deviceLabel"]
        updates = ["constant", "set every repeat"]
        p = self.params
        p["stimulus"] = Param(
            stimulus, valType="str", inputType="file", allowedTypes=[], categ="Basic",
            updates="constant", allowedUpdates=updates,
            label=_translate("Stimulus"),
            hint=_translate("An image file, one of vtexp's stimuli (shape:shape=square, "
                            "letter:letter=A, surface:surface=ball) or a pattern file "
                            "written by 'vtexp encode --json'; $column for a conditions "
                            "file's column"))
        p["pipeline"] = Param(
            pipeline, valType="str", inputType="choice", allowedVals=PIPELINES, categ="Basic",
            updates="constant", allowedUpdates=updates,
            label=_translate("Encoding pipeline"),
            hint=_translate("How the image becomes a pattern on the array (not used for a "
                            "pattern file)"))
        p["coding"] = Param(
            coding, valType="str", inputType="single", categ="Basic",
            updates="constant", allowedUpdates=updates,
            label=_translate("Coding"),
            hint=_translate("How the pattern is played: sequential-trace, contour-modes, "
                            "pulse-trains; empty: the pipeline's paper's"))
        p["encodingParams"] = Param(
            encodingParams, valType="str", inputType="single", categ="Basic",
            updates="constant", allowedUpdates=updates,
            label=_translate("Encoding parameters"),
            hint=_translate("key=value, key=value (as vtexp encode --param)"))
        p["codingParams"] = Param(
            codingParams, valType="str", inputType="single", categ="Basic",
            updates="constant", allowedUpdates=updates,
            label=_translate("Coding parameters"),
            hint=_translate("key=value, key=value (as vtexp encode --coding-param), e.g. "
                            "duration_ms=60, soa_ms=60"))
        p["device"] = Param(
            device, valType="str", inputType="single", categ="Device",
            label=_translate("Device"),
            hint=_translate("sim (simulated, nothing driven), emulator (the firmware "
                            "emulated on a pseudo-terminal) or serial:PORT (serial:COM3, "
                            "serial:/dev/ttyACM0)"))
        p["profile"] = Param(
            profile, valType="str", inputType="single", categ="Device",
            label=_translate("Device profile"),
            hint=_translate("A shipped profile (vest_6x8, pad_20x20, sma_5x5) or a profile "
                            "YAML file: the array's geometry, drive and safety limits"))
        p["deviceLabel"] = Param(
            deviceLabel, valType="str", inputType="single", categ="Device",
            label=_translate("Device name"),
            hint=_translate("The name the array has in PsychoPy's device manager; "
                            "components with the same name share one device"))

    # -- where the stimuli come from ---------------------------------------------------------
    def _conditions_files(self):
        """The literal conditions files of the loops around this component's routine,
        outermost first (a file named by code is known only when its loop starts)."""
        stack, around = [], None
        for entry in self.exp.flow:
            kind = type(entry).__name__
            if kind == "LoopInitiator":
                stack.append(entry.loop)
            elif kind == "LoopTerminator":
                if stack:
                    stack.pop()
            elif getattr(entry, "name", None) == self.parentName and around is None:
                around = list(stack)
        files = []
        for loop in around or []:
            param = loop.params.get("conditionsFile")
            if param is None or not str(param.val).strip() or str(param.val).startswith("$"):
                continue
            files.append(str(param))            # a Python string literal
        return files

    # -- code ----------------------------------------------------------------------------------
    def writeInitCode(self, buff):
        inits = getInitVals(self.params, "PsychoPy")
        p = self.params
        label = repr(str(p["deviceLabel"].val) or "tactileArray")
        code = (
            f"# --- {p['name'].val}: the tactile array, opened and checked once, and every "
            "stimulus compiled and checked against its profile's safety limits ---\n"
            f"if deviceManager.getDevice({label}) is None:\n"
            f"    deviceManager.addDevice(\n"
            f"        deviceClass='vtexp.builder:TactileArray', deviceName={label},\n"
            f"        device={inits['device']}, profile={inits['profile']}, name={label})\n"
            f"deviceManager.getDevice({label}).open(\n"
            f"    device={inits['device']}, profile={inits['profile']})\n"
            f"runAtExit.append(deviceManager.getDevice({label}).close)\n"
            f"{p['name'].val} = vtexp_builder.TactileStimulus(\n"
            f"    deviceManager.getDevice({label}), name='{p['name'].val}', folder=_thisDir)\n"
        )
        buff.writeIndentedLines(code)
        files = self._conditions_files()
        exprs = ", ".join(f"{arg}={str(p[key])!r}" for key, arg in SPEC_PARAMS.items())
        conds = ", ".join(f"({f}, data.importConditions({f}))" for f in files)
        code = (f"{p['name'].val}.prepare_rows([{conds}], globals(), {exprs})\n")
        buff.writeIndentedLines(code)

    def writeRoutineStartCode(self, buff):
        p = self.params
        args = ", ".join(f"{arg}={p[key]}" for key, arg in SPEC_PARAMS.items())
        buff.writeIndentedLines(f"{p['name'].val}.start_routine(globalClock, {args})\n")

    def writeFrameCode(self, buff):
        name = self.params["name"].val
        buff.writeIndentedLines(f"\n# *{name}* updates\n")
        indented = self.writeStartTestCode(buff)
        if indented:
            if self.params["syncScreenRefresh"].val:
                buff.writeIndentedLines(f"win.callOnFlip({name}.play)  # starts with the flip\n")
            else:
                buff.writeIndentedLines(f"{name}.play()\n")
            buff.setIndentLevel(-indented, relative=True)
        indented = self.writeStopTestCode(buff, extra=f" or {name}.finished")
        if indented:
            buff.writeIndentedLines(f"{name}.stop()\n")
            buff.setIndentLevel(-indented, relative=True)

    def writeRoutineEndCode(self, buff):
        name = self.params["name"].val
        code = (
            f"# {name}: stopped if it still plays; the device-reported onset of every pulse "
            "(on PsychoPy's clock) into the data file\n"
            f"for _key, _value in {name}.data().items():\n"
            "    thisExp.addData(_key, _value)\n"
        )
        buff.writeIndentedLines(code)

    def writeExperimentEndCode(self, buff):
        label = repr(str(self.params["deviceLabel"].val) or "tactileArray")
        buff.writeIndentedLines(
            f"# every actuator off, the tactile array closed\n"
            f"if deviceManager.getDevice({label}) is not None:\n"
            f"    deviceManager.getDevice({label}).close()\n")
