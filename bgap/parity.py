from bgap.runner.numerics import command

main = command("bgap.commands.parity")
if __name__ == "__main__":
    main()
