from tasks.world.phases import token_patch


def test_token_patch_keeps_a_latent_frame_at_64_tokens_or_fewer():
    assert token_patch(8, 8) == 1 and token_patch(4, 4) == 1
    assert token_patch(16, 16) == 2 and token_patch(32, 32) == 4
    assert token_patch(12, 16) == 2  # 6 x 8 = 48 tokens
    assert token_patch(16, 16, max_tokens=256) == 1
