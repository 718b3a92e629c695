"""The U2U links of one recorded second, exactly as the world had them: `link_mask`
(within R_comm AND SINR >= Gamma, with the other live UAVs interfering) on the live UAVs'
3-D positions. Used by the report's map and the live view's map."""

from __future__ import annotations


def u2u_links(uavs: list[dict], mission) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:  # noqa: ANN001 - Mission
    """([(i, j)] heard both ways, [(i, j)] heard one way only), i < j UAV ids, from rows
    {"id", "alive", "pos_ned"} (a UAV without a position takes no part). A pair heard both
    ways is an edge of the swarm graph (lambda_2)."""
    import torch

    from plmarl_sitl.model.graph import link_mask

    live = [u for u in uavs if u.get("alive", True) and u.get("pos_ned") is not None]
    if len(live) < 2:
        return [], []
    pos = torch.tensor([u["pos_ned"] for u in live], dtype=torch.float32)  # the world's dtype (`SitlWorld.positions`)
    rx, _ = link_mask(pos, torch.ones(len(live), dtype=torch.bool), mission.channel, mission.radii.comm_m)
    both, one = [], []
    for a in range(len(live)):
        for b in range(a + 1, len(live)):
            ab, ba = bool(rx[a, b]), bool(rx[b, a])
            pair = tuple(sorted((live[a]["id"], live[b]["id"])))
            if ab and ba:
                both.append(pair)
            elif ab or ba:
                one.append(pair)
    return both, one
