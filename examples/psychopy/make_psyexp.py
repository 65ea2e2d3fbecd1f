"""Writes tactile_shapes.psyexp, the Builder experiment of this folder, through PsychoPy's
own experiment API (as Builder saves it). Run it again after changing the experiment here:

    python examples/psychopy/make_psyexp.py

Needs PsychoPy and the psychopy-vtexp plugin (see the README, "PsychoPy Builder").
"""

from pathlib import Path

from psychopy import experiment, plugins
from psychopy.experiment.components.keyboard import KeyboardComponent
from psychopy.experiment.components.text import TextComponent
from psychopy.experiment.loops import TrialHandler

plugins.activatePlugins()
from psychopy_vtexp import TactileStimulusComponent  # noqa: E402

HERE = Path(__file__).parent
exp = experiment.Experiment()
exp.name = "tactile_shapes"
s = exp.settings.params
s["expName"].val = "tactile_shapes"
s["Show info dlg"].val = False          # Builder's participant dialog: tick it for a study
s["Full-screen window"].val = False
s["Window size (pixels)"].val = "[1024, 768]"
s["color"].val = "[-1, -1, -1]"
s["keyboardBackend"].val = "PsychToolbox"

trial = exp.addRoutine("trial")
fix = TextComponent(exp, "trial", name="fixation", text="+", letterHeight=0.1,
                    startVal=0.0, stopType="duration (s)", stopVal=0.4)
tactile = TactileStimulusComponent(
    exp, "trial", name="tactile", startVal=0.4, stopVal="", durationEstim=0.8,
    device="emulator", profile="vest_6x8", stimulus="$stimulus", pipeline="edge-trace",
    coding="sequential-trace", codingParams="duration_ms=40, soa_ms=40")
tactile.params["stimulus"].updates = "set every repeat"
prompt = TextComponent(exp, "trial", name="prompt",
                       text="Which shape?\n1 square   2 triangle   3 circle",
                       letterHeight=0.05, startType="condition",
                       startVal="tactile.status == FINISHED", stopVal="")
answer = KeyboardComponent(exp, "trial", name="answer", allowedKeys="'1','2','3'",
                           startType="condition", startVal="tactile.status == FINISHED",
                           stopVal="", storeCorrect=True, correctAns="$corrAns", registerOn="release",
                           forceEndRoutine=True)
for comp in (fix, tactile, prompt, answer):
    trial.addComponent(comp)

loop = TrialHandler(exp, name="trials", loopType="random", nReps=1,
                    conditionsFile="conditions.csv", endPoints=[0, 1])
exp.flow.addLoop(loop, 0, 1)
exp.flow.addRoutine(trial, 1)
exp.saveToXML(str(HERE / "tactile_shapes.psyexp"), makeLegacy=False)
print(f"written: {HERE / 'tactile_shapes.psyexp'}")
