"""TruthMeasurer.trial without a graph: a setting with no block left to place (the blocks off
the stack lie on their side or out of reach) is skipped and built anew."""

from types import SimpleNamespace

from katana_paper.truth import TruthMeasurer


class NoFreeBlock:
    """The fovea finds a location on a two-stack; no other block is on the table."""

    def __init__(self) -> None:
        self.placed = 0

    def find(self, height: int, action: int):
        position = SimpleNamespace(x=0.16, y=0.0, z=0.075)
        instance = SimpleNamespace(support_ids=["red", "green"],
                                   placement=SimpleNamespace(position=position))
        return SimpleNamespace(found=True, instance=instance)

    def latest_truth(self):
        return SimpleNamespace(blocks=[])

    def pick_and_place(self, block, placement):
        self.placed += 1
        raise AssertionError("nothing to pick")


def test_a_setting_without_a_free_block_is_skipped_and_built_anew() -> None:
    client = NoFreeBlock()
    measurer = TruthMeasurer(client, seed=0, max_height=3, block_height_m=0.03)
    measurer._stack_intact = lambda height: True  # the two-stack stands
    assert measurer.trial(2, 6) is None
    assert measurer.last_skip == "no_free_block"
    assert measurer.progress.skipped["no_free_block"] == 1
    assert measurer.stack is None and client.placed == 0  # the next trial builds anew
