"""Task files (errors with line and field), sequence graph, and the three modes on scripted sessions."""

import json

import numpy as np
import pytest

from tracker.assembly import TaskFileError, build_mode, list_presets, load_preset, parse_task
from tracker.assembly.connection_monitor import specs_from_structure
from tracker.assembly.modes.guess import choose_guess
from tracker.assembly.modes.learning import assign_words
from tracker.assembly.part_graph import PartGraph
from tracker.assembly.sequence_graph import SequenceGraph
from tracker.assembly.synthetic import build_up_session, default_table_to_camera
from tracker.assembly.task_file import SentenceTask
from tracker.geometry.pose import Pose

GOOD = """id: t
mode: guess
parts:
  - {name: red}
  - {name: green}
structures:
  - name: s
    connections:
      - {first: red, second: green, p: [1, 0, 0]}
"""


def _error(text):
    with pytest.raises(TaskFileError) as exc:
        parse_task(text, "task.yaml")
    return str(exc.value)


def test_task_file_errors_name_line_and_field():
    assert parse_task(GOOD).structures[0].connections[0].second == "green"
    msg = _error(GOOD.replace("second: green", "second: blue"))
    assert "task.yaml:9" in msg and "structures[0].connections[0].second" in msg and "unknown part 'blue'" in msg
    msg = _error(GOOD.replace("  - {name: green}", "  - {name: red}"))
    assert "task.yaml:5" in msg and "parts[1].name" in msg and "duplicate part name 'red'" in msg
    msg = _error("id: l\nmode: learning\nparts: [{name: a}, {name: b}]\nsentences:\n"
                 "  - source_sentence: x\n    words: [uno, dos, tres]\n")
    assert "task.yaml:6" in msg and "sentences[0].words" in msg and "3 words" in msg and "2 cubes" in msg
    msg = _error(GOOD.replace("p: [1, 0, 0]", "p: [1, 0]"))
    assert "task.yaml:9" in msg and "connections[0].p" in msg
    assert "YAML syntax" in _error("id: [unclosed\n")


def test_sentence_task_model():
    s = SentenceTask(source_sentence="Αύριο πηγαίνω στην παραλία", words=["Mañana", "voy", "a", "la", "playa"],
                     alternatives=[["voy", "a", "la", "playa", "Mañana"]], distractors=["el"])
    assert s.source_language == "el" and len(s.accepted_orders()) == 2
    with pytest.raises(ValueError, match="alternatives"):
        SentenceTask(source_sentence="x", words=["a", "b"], alternatives=[["a", "c"]])


def test_presets_load_and_match_the_simulator_structures():
    ids = {p["id"] for p in list_presets()}
    assert {"guidance-5-cubes", "guess-structures", "learning-4-words", "learning-5-words"} <= ids
    task = load_preset("guess-structures")
    lay = PartGraph.from_connections(specs_from_structure(task, task.structure("tower-with-wings"))).layout()
    a = task.edge
    np.testing.assert_allclose(lay["blue"].t, [0, 2 * a, 0], atol=1e-12)
    np.testing.assert_allclose(lay["orange"].t, [-a, 0, 0], atol=1e-12)
    words = load_preset("learning-5-words").sentences[0].words
    assert words == ["Vivo", "en", "el", "primer", "piso"]


def test_sequence_graph_states_and_plan():
    task = load_preset("guidance-5-cubes")
    s = task.structures[0]
    sg = SequenceGraph(PartGraph.from_connections(specs_from_structure(task, s)), task.edge)
    # yellow on top of green: any block holding yellow without green is unstable
    assert all(not ("yellow" in b and "green" not in b and len(b) > 1) for x in sg.nodes for b in x)
    path = sg.plan_path(s.plan)
    assert path[0] == sg.start and path[-1] == sg.goal and len(path) == 5
    assert len(sg.nodes) == 16 and sg.count_paths() == 24


def test_guess_tie_break():
    assert choose_guess([0.5, 0.25, 0.0], [0, 0, 0], None) == (0, False)
    assert choose_guess([0.5, 0.5, 0.0], [0.0, 0.0, 0.0], 1) == (1, True)  # last tie-free leader kept
    assert choose_guess([0.5, 0.5, 0.0], [0.1, 0.9, 0.0], None) == (1, True)  # no earlier leader: evidence
    assert choose_guess([0.5, 0.5, 0.5], [0.0, 0.0, 0.0], 2) == (2, True)
    assert choose_guess([0.5, 0.5, 0.0], [0.0, 0.0, 0.0], 2) == (0, True)  # last leader not tied: evidence, order
    assert choose_guess([0.5, 0.5, 0.0], [0.1, 0.2, 0.0], None, previous=0) == (0, True)  # sticky previous guess
    assert choose_guess([0.5, 0.5, 0.0], [0.1, 0.5, 0.0], None, previous=0) == (1, True)


def test_word_assignment_reproducible():
    s = load_preset("learning-5-words").sentences[0]
    cubes = ["red", "green", "blue", "yellow", "orange", "purple", "cyan"]
    a1, a2 = assign_words(s, cubes, 11), assign_words(s, cubes, 11)
    assert a1 == a2 and sorted(a1.values()) == sorted(s.words + s.distractors)
    assert any(assign_words(s, cubes, k) != a1 for k in range(12, 20))
    with pytest.raises(ValueError, match="only 3 cubes"):
        assign_words(s, cubes[:3], 0)


def _run(mode, frames, T):
    state = None
    for t, poses, _ in frames:
        state = mode.update(t, poses, T)
        json.dumps(state.to_dict())
    return state


@pytest.mark.parametrize("true_name", ["T-tower", "L", "tower-with-wings"])
def test_guess_mode_scripted_session(true_name):
    task = load_preset("guess-structures")
    T = default_table_to_camera()
    s = task.structure(true_name)
    g = PartGraph.from_connections(specs_from_structure(task, s))
    order = {"T-tower": ["red", "green", "yellow", "blue", "orange"], "L": ["red", "green", "blue", "yellow", "orange"],
             "tower-with-wings": ["red", "yellow", "green", "orange", "blue"]}[true_name]
    frames = build_up_session(g, order, T, np.random.default_rng(5), yaw=0.3)
    mode = build_mode(task)
    said = set()
    for t, poses, _ in frames:  # a structure is named only while it leads alone
        st = mode.update(t, poses, T).to_dict()
        top = st["ranking"][0]["completed"]
        if st["tied"] and top > 0 and not st["complete"]:
            assert st["instruction"].startswith("Not sure yet"), st["instruction"]
            said.add("not sure")
        elif not st["tied"] and not st["complete"]:
            assert st["instruction"].startswith("I think you are building the"), st["instruction"]
            assert st["confidence"] > 0
    if true_name != "tower-with-wings":  # the T-tower and the L begin with the same connections
        assert "not sure" in said
    state = mode.last_state.to_dict()
    assert state["guess"] == true_name and state["complete"]
    assert state["ranking"][0]["structure"] == true_name and state["ranking"][0]["completed"] == 4
    assert state["confidence"] > 0.4
    detected = {frozenset((e.first, e.second)) for e in mode.connection_events() if e.type == "connected"}
    assert {frozenset((c.first, c.second)) for c in s.connections} <= detected
    hints = mode.connection_hints()
    assert len(hints) >= 4 and all(h.locked for h in hints if h.n_particles == mode.params.N_max)


def test_guidance_mode_steps_target_and_completion():
    task = load_preset("guidance-5-cubes")
    T = default_table_to_camera()
    s = task.structures[0]
    g = PartGraph.from_connections(specs_from_structure(task, s))
    frames = build_up_session(g, s.plan, T, np.random.default_rng(2), frames_per_step=6)
    mode = build_mode(task)
    first = mode.update(*frames[0][:2], T).to_dict()
    assert first["next_step"]["part"] == "green" and first["next_step"]["anchor"] == "red"
    assert "right of the red" in first["instruction"] and not first["complete"]
    # the target pose for green is one edge to the right of red, on the table
    tgt = np.array(first["next_step"]["target_pose"]["t"])
    red = frames[0][1]["red"].t
    off = T.R.T @ (tgt - red)
    np.testing.assert_allclose(off, [task.edge, 0, 0], atol=0.01)
    seen_steps, state = [], None
    for t, poses, _ in frames:
        state = mode.update(t, poses, T).to_dict()
        seen_steps.append(state["progress"]["done"])
        if not state["complete"]:
            assert state["warning"] is None
    assert state["complete"] and state["progress"] == {"done": 4, "total": 4, "unit": "steps"}
    assert seen_steps == sorted(seen_steps)


@pytest.mark.parametrize("swap", [False, True])
def test_learning_mode_verdicts(swap):
    task = load_preset("learning-4-words")
    T = default_table_to_camera()
    sentence = task.sentences[0]
    row = ["red", "green", "blue", "yellow"]
    assignment = dict(zip(row, sentence.words, strict=True)) | {"orange": "gusto", "purple": "leche"}
    if swap:  # the user swaps two words: the row is read but two positions are wrong
        assignment["green"], assignment["blue"] = assignment["blue"], assignment["green"]
    mode = build_mode(task, parts=None, seed=0, sentence=0, assignment=assignment)
    from tracker.assembly.connection_monitor import ConnectionSpec

    pairs = zip(row[:-1], row[1:], strict=True)
    specs = [ConnectionSpec(a, b, np.array([task.edge, 0, 0]), np.eye(3)) for a, b in pairs]
    frames = build_up_session(PartGraph.from_connections(specs), row, T, np.random.default_rng(4),
                              extra_parts=["orange", "purple"])
    completes = [mode.update(t, p, T).complete for t, p, _ in frames]
    state = mode.last_state.to_dict()
    assert state["row"] == row
    correct = [v["correct"] for v in state["verdicts"]]
    assert state["progress"] == {"done": sum(correct), "total": 4, "unit": "words"}  # words, not connections
    if swap:
        assert correct == [True, False, False, True] and not any(completes)
    else:
        assert all(correct) and state["complete"] and completes[-1]
        # taking the row apart afterwards keeps the verdict until the next round (reset)
        t_end = frames[-1][0]
        last = frames[-1][1].items()
        apart = {n: Pose(p.t + T.R @ np.array([0.1 * i, 0.0, 0.0]), p.q) for i, (n, p) in enumerate(last)}
        for k in range(8):
            kept = mode.update(t_end + (k + 1) / 30, apart, T).to_dict()
        assert kept["complete"] and kept["instruction"].startswith("¡Muy bien!")
        mode.reset()
        assert not mode.update(t_end + 1.0, apart, T).complete
    assert {w["word"] for w in state["words"] if w["is_distractor"]} == {"gusto", "leche"}
    # the list shown to the user does not give the answer away: not in the sentence's order
    assert [w["word"] for w in state["words"] if not w["is_distractor"]] != list(sentence.words)


@pytest.mark.parametrize("ahead", [True, False])
def test_guidance_check_ahead(ahead):
    """Green–blue made before red–green: confirmed in the background only with check_ahead."""
    task = load_preset("guidance-5-cubes")
    T = default_table_to_camera()
    s = task.structures[0]
    g = PartGraph.from_connections(specs_from_structure(task, s))
    frames = build_up_session(g, ["green", "blue"], T, np.random.default_rng(8),
                              extra_parts=["red", "orange", "yellow"])
    mode = build_mode(task, check_ahead=ahead)
    state = _run(mode, frames, T).to_dict()
    assert state["next_step"]["part"] == "green" and state["step"] == 0
    gb = next(c for c in state["connections"] if {c["first"], c["second"]} == {"green", "blue"})
    assert (gb["state"] == "connected") == ahead
    assert state["progress"]["done"] == (1 if ahead else 0)
