"""Consortium-chain client for the UMC, TMC and MMC contracts (thesis Ch. 5.3, 7.7).

One interface, two backends: ``client.Chain.embedded`` (eth-tester + py-evm, in process, on
disk with ``durable``) and ``client.Chain.rpc`` (any JSON-RPC node, e.g. anvil or a consortium
PoA chain). Import the submodules directly; ``qos`` is pure Python and never pulls in web3.
"""
